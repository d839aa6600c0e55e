/// @file dicom_series.h
/// @brief A DICOM series folder: files scanned (headers in forked children), grouped by
///        Series Instance UID, ordered by position along the slice normal, checked for gaps,
///        uneven steps and gantry tilt, then read file by file in parallel. Internal to volume/.
#pragma once

#include "volume/image.h"
#include "volume/image_io.h"

#include <memory>
#include <string>

namespace flyover::imageio {

/// @throw InputError naming the folder or the file.
std::unique_ptr<ImageSource> openDicomFolder(const std::string& dir, const ImageReadOptions& options);

} // namespace flyover::imageio
