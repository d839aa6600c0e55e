/// @file nifti1.h
/// @brief NIfTI-1 voxels read by flyover once ITK has read and checked the header: ITK stays
///        the reference for the geometry, but its NiftiImageIO can only read a region of a
///        gzipped file by inflating it from the start, so .nii.gz was first inflated to a
///        temporary file. Here the voxels are inflated while they are read (raw_voxels.h), and
///        a plain .nii is read by pread. Values are exactly ITK's: same bytes (ITK's
///        vox_offset), same byte order, same scl_slope/scl_inter arithmetic (tests compare the
///        two on every voxel type, both byte orders and scaled headers). Internal to volume/.
#pragma once

#include "volume/image.h"
#include "volume/io/data_size.h"

#include <memory>
#include <string>

namespace flyover::imageio {

/// The voxels of the NIfTI-1 file `path` (a .nii or .nii.gz, or the .hdr of a .hdr/.img(.gz)
/// pair) whose header ITK has read into `g` and `data`; null when its layout is one flyover
/// leaves to ITK (Analyze 7.5 headers, scaled double voxels, anything unexpected).
/// `itkBitpix` is ITK's "bitpix" of the header, checked against flyover's reading; `warning`,
/// when not empty, is added to the source's warnings.
std::unique_ptr<ImageSource> openNifti1Voxels(const std::string& path, const ImageGeometry& g, const DataFile& data,
                                              const std::string& itkBitpix, const std::string& description,
                                              const std::string& warning);

} // namespace flyover::imageio
