/// @file nifti2.h
/// @brief NIfTI-2 (540-byte header; .nii, .nii.gz, .hdr + .img, either byte order), read by
///        flyover itself: ITK 5.2 reads NIfTI-1 only (see nifti2.cpp for why nifticlib's
///        reader cannot be used and how the header is interpreted). Internal to volume/.
#pragma once

#include "volume/image.h"

#include <memory>
#include <string>

namespace flyover::imageio {

/// True when the file (plain or gzipped) begins with sizeof_hdr = 540 in either byte order.
bool isNifti2(const std::string& path);

/// Opens a NIfTI-2 file, streamed by slab (gzip inflated while read); `warning`,
/// when not empty, is added to the source's warnings.
/// @throw InputError naming the file.
std::unique_ptr<ImageSource> openNifti2(const std::string& path, const std::string& warning = "");

} // namespace flyover::imageio
