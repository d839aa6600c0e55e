/// @file geometry_check.h
/// @brief Checks of a header's geometry and voxel layout before any voxel is read: 3D, one
///        time point, scalar, supported type, positive finite spacing, finite origin,
///        orthonormal direction cosines. Internal to volume/.
#pragma once

#include "volume/image.h"

#include <itkImageIOBase.h>

#include <string>

namespace flyover::imageio {

/// @throw InputError naming `path`: empty dimension, bad spacing or origin, direction
///        cosines that are not orthonormal.
void validateGeometry(const ImageGeometry& g, const std::string& path);

/// Checks dimension, pixel type and geometry of a header ITK has read.
/// @throw InputError naming `path`.
ImageGeometry checkHeader(itk::ImageIOBase& io, const std::string& path);

} // namespace flyover::imageio
