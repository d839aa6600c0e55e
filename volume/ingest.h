/// @file ingest.h
/// @brief Dense HU image -> sparse, isotropic openvdb::FloatGrid of Hounsfield units.
///
/// Air outside the body (HU below `outsideAirHu` and connected, within its axial slice,
/// to the slice border) becomes the inactive background (`backgroundHu`); everything else
/// is active. Anisotropic images are resampled to cubic voxels by trilinear interpolation.
/// The grid transform maps index space to LPS world millimetres, honouring origin and
/// direction cosines (an oblique scan gives an affine transform).
#pragma once

#include "volume/image.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

namespace flyover {

struct IngestParams {
    double voxelMm = 0.0;          ///< isotropic voxel size (mm); 0 = the smallest input spacing
    double outsideAirHu = -500.0;  ///< air outside the body is below this (HU)
    double backgroundHu = -1000.0; ///< value of the inactive background (HU)
    static constexpr int VERSION = 1;
};

/// One summary of the grid produced, for the manifest.
struct IngestReport {
    double voxelMm = 0;
    int64_t activeVoxels = 0;
    int64_t memoryBytes = 0;
    std::array<int64_t, 3> inputSize{0, 0, 0};
    Vec3d inputSpacingMm;
};

/// @throw InputError when the image is empty or its geometry is invalid.
openvdb::FloatGrid::Ptr ingestImage(const Image3<float>& image, const IngestParams& params,
                                    IngestReport* report = nullptr, Progress* progress = nullptr);

/// The transform of an isotropic grid with the given world geometry: index (0,0,0) at
/// `originMm`, index axes along the columns of `direction`, cubic voxels of `voxelMm`.
openvdb::math::Transform::Ptr makeGridTransform(const Vec3d& originMm, const Mat3d& direction,
                                                double voxelMm);

} // namespace flyover
