/// @file image_io.h
/// @brief Reading and writing dense images in standard formats through ITK's IO
///        (NIfTI .nii/.nii.gz, NRRD, MetaImage; DICOM series directories for reading).
///        World geometry is LPS, as ITK reports it; NIfTI's RAS affine is converted by ITK.
#pragma once

#include "volume/image.h"

#include <cstdint>
#include <string>

namespace flyover {

/// Reads a scalar 3D image, converting its voxels to float.
/// @throw InputError naming the file when it is missing, unreadable, not 3D, not scalar,
///        has non-positive spacing, or holds NaN/Inf voxels.
Image3<float> readImage(const std::string& path);

/// Writes an image; the format follows the extension (.nii.gz, .nii, .nrrd, .mha, ...).
/// The file is written to a temporary name and renamed into place.
/// @throw InputError when the file cannot be written.
void writeImage(const Image3<int16_t>& image, const std::string& path);
void writeImage(const Image3<uint8_t>& image, const std::string& path);

} // namespace flyover
