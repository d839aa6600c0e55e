/// @file ingest.h
/// @brief A scan (an ImageSource, or a dense image) -> sparse, isotropic openvdb::FloatGrid
///        of Hounsfield units, built slab by slab.
///
/// Air outside the body (HU below `outsideAirHu` and connected, within its slice of the
/// output grid, to the slice border) becomes the inactive background (`backgroundHu`);
/// everything else is active. The output lattice keeps the input's index axes (direction
/// cosines) and voxel (0,0,0) centre, with cubic voxels of `voxelMm`; the grid transform
/// maps index space to LPS world millimetres (an oblique scan gives an affine transform).
///
/// Interpolation: none when the input voxels are already cubic of that size (values are
/// copied); otherwise trilinear: bilinear within each input slice, linear between the two
/// slices that bracket the output voxel, at the slices' true positions. So a DICOM series
/// with accepted gaps, uneven steps or gantry tilt (ImageSource::isRegular() false) lands
/// where its slices really are; output voxels outside every slice's footprint (the edges
/// of a tilted stack) are background.
///
/// Memory: the grid, plus one output slab (8 slices: a byte mask, and floats unless every
/// slice is an input slice copied unchanged, which is read in place), plus the input slices
/// that slab needs (as float, and in their native type while read), plus
/// whatever the source holds (ImageSource::heldBytes(): 0 when it streams).
#pragma once

#include "volume/image.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace flyover {

struct IngestParams {
    double voxelMm = 0.0;          ///< isotropic voxel size (mm); 0 = the smallest input spacing
    double outsideAirHu = -500.0;  ///< air outside the body is below this (HU)
    double backgroundHu = -1000.0; ///< value of the inactive background (HU)
    std::string dicomSeries;       ///< DICOM folder: Series Instance UID to read ("" = most slices)
    bool allowGaps = false;        ///< DICOM: accept missing slices / uneven steps (with a warning)
    static constexpr int VERSION = 2;
};

/// One summary of the grid produced, for the manifest.
struct IngestReport {
    double voxelMm = 0;
    int64_t activeVoxels = 0;
    int64_t memoryBytes = 0;                  ///< grid->memUsage()
    std::array<int64_t, 3> inputSize{0, 0, 0};
    Vec3d inputSpacingMm;
    Vec3d inputOriginMm;                      ///< LPS mm, voxel (0,0,0) centre
    Mat3d inputDirection = identityMat3();    ///< columns: LPS directions of i, j, k
    std::array<int64_t, 3> gridSize{0, 0, 0}; ///< output lattice, index (0,0,0) at gridOriginMm
    Vec3d gridOriginMm;                       ///< LPS mm of grid index (0,0,0)
    std::string interpolation;                ///< how output values were obtained
    std::string source;                       ///< format, library, read mode
    int64_t sourceHeldBytes = 0;              ///< what the source held for the whole read
    int64_t workingBytes = 0;                 ///< slab and input-slice buffers at their largest
    std::vector<std::string> warnings;        ///< from the source (gaps accepted, tilt corrected, ...)
};

/// @throw InputError naming the source when its geometry is unusable, its data cannot be
///        read, or every voxel is outside-body air; ParameterError for a bad voxelMm.
openvdb::FloatGrid::Ptr ingestImage(ImageSource& source, const IngestParams& params,
                                    IngestReport* report = nullptr, Progress* progress = nullptr);

/// The same for an image already in memory (tests, phantoms).
openvdb::FloatGrid::Ptr ingestImage(const Image3<float>& image, const IngestParams& params,
                                    IngestReport* report = nullptr, Progress* progress = nullptr);

/// The transform of an isotropic grid with the given world geometry: index (0,0,0) at
/// `originMm`, index axes along the columns of `direction`, cubic voxels of `voxelMm`.
openvdb::math::Transform::Ptr makeGridTransform(const Vec3d& originMm, const Mat3d& direction,
                                                double voxelMm);

} // namespace flyover
