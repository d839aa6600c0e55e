/// @file ct_slice.h
/// @brief Axis-aligned CT slices in radiological display, windowed to 8-bit grey: for the
///        viewer's slices and the polyp candidates' crops, the same geometry in both.
///
/// Radiological display: axial: the patient's right on the image's left, anterior up;
/// coronal: superior up, right on the left; sagittal: superior up, anterior on the left.
#pragma once

#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// The pixel <-> LPS mapping of a CT slice image: pixel (c, r) has its centre at
/// originMm + c * pixelMm * colDir + r * pixelMm * rowDir.
struct SliceGeometry {
    std::string plane;
    Vec3d originMm, rowDir, colDir;
    double pixelMm = 1;
    int width = 0, height = 0;
};

struct SliceImage {
    SliceGeometry geometry;
    std::vector<uint8_t> gray;  ///< width x height, top row first
};

/// The slice of `plane` ("axial", "coronal", "sagittal") through `pointMm` that covers the box
/// [loMm, hiMm] (LPS mm) with square pixels of `pixelMm`.
/// @throw ParameterError for an unknown plane or a pixel size that is not positive.
SliceGeometry sliceGeometry(const std::string& plane, const Vec3d& pointMm, const Vec3d& loMm, const Vec3d& hiMm,
                            double pixelMm);

/// HU sampled trilinearly at the pixel centres, mapped through the window (grey 0 at
/// level - window/2, 255 at level + window/2).
SliceImage sampleSlice(const openvdb::FloatGrid& hu, const SliceGeometry& geometry, double window, double level);

} // namespace flyover
