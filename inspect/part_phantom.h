/// @file part_phantom.h
/// @brief A synthetic industrial CT of a cast-like part with internal voids and their truth
///        (thesis chapter VII), generated slice by slice so that 1024^3 and larger
///        need memory for a few slices only.
///
/// The part (index units, N = size, axis along k): a cylinder of radius 0.34 N from
/// k = 0.10 N to 0.90 N, a flange of radius 0.46 N from k = 0.10 N to 0.22 N, and a through
/// bore of radius 0.08 N (open at both ends: outside air). Inside the material:
/// - pores: ellipsoids 3 to 16 voxels across, half spheres, half elongated (prolate, long axis
///   1.8-3 times the short ones, randomly oriented); count `pores` (0 = 12 x (N/128)^2);
/// - one internal crack: a planar elliptic disc 1.8 voxels thick, semi-axes 14 x 10 voxels,
///   roughly tangential to the wall (tilted up to ~20 degrees);
/// - one crack open to the surface: a disc 2.2 voxels thick, semi-axes 12 x 8 voxels, cut
///   into the outer wall (half of it outside the part): part of the outside air, not a void.
/// Every void keeps at least 4 voxels of material to the part's surfaces and to other voids.
///
/// Grey values: each voxel's material fraction f (exact partial volume, from 4x4x4 point
/// samples where the voxel cube can meet a surface), blurred by a Gaussian (blurVoxels, kernel
/// radius ceil(3 sigma), normalised so the blur keeps every volume), grey = air + f (material -
/// air) + Gaussian noise, rounded and clamped to uint16.
///
/// Truth, from the voxelised volume (the same fractions the image is made of): per void its
/// volume = sum of its voxels' air fractions (the void's exact partial volume), voxel count
/// (air fraction >= 0.5), centroid (air-fraction weighted), max extent (largest distance
/// between the centres of its voxels counted), equivalent diameter (6V/pi)^(1/3); the part's
/// material volume = sum of material fractions; porosity = internal voids / (material +
/// internal voids) x 100. Deterministic for a given (params): noise is seeded per row.
/// World frame: LPS mm, identity direction, the grid centred on the origin.
#pragma once

#include "volume/image.h"
#include "volume/progress.h"
#include "volume/vec3.h"

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace flyover {

struct PartPhantomParams {
    int size = 128;               ///< voxels along each axis (112..2048)
    uint64_t seed = 1;
    double voxelMm = 0.1;         ///< isotropic voxel size (mm)
    double airGrey = 6000;        ///< grey value of air (uint16 range)
    double materialGrey = 30000;  ///< grey value of the material (> airGrey)
    double noiseSigma = -1;       ///< Gaussian noise SD (grey); < 0: 4% of (material - air)
    double blurVoxels = 0.6;      ///< Gaussian blur SD (voxels, 0..2)
    int pores = 0;                ///< number of pores; 0: 12 x (size/128)^2
};

struct PartVoidTruth {
    int id = 0;                   ///< 1..N in generation order
    std::string kind;             ///< "pore", "crack" or "open_crack"
    bool internal = true;         ///< false for the open crack (joined to the outside air)
    Vec3d centerLps;              ///< the shape's centre (LPS mm)
    Vec3d semiAxesVoxels;         ///< the shape's semi-axes (voxels; a crack: a, b, half thickness)
    Vec3d centroidLps;            ///< truth centroid from the voxelised volume (LPS mm)
    double volumeMm3 = 0;         ///< partial volume of its air inside the part (mm^3)
    double equivalentDiameterMm = 0;
    double maxExtentMm = 0;
    int64_t voxels = 0;           ///< voxels whose air fraction is >= 0.5
};

struct PartTruth {
    ImageGeometry geometry;
    PartPhantomParams params;     ///< with the defaults resolved (noiseSigma, pores)
    std::vector<PartVoidTruth> voids;
    double materialVolumeMm3 = 0;
    double internalVoidVolumeMm3 = 0;
    double porosityPercent = 0;
};

/// Receives slice k (size x size uint16, i fastest), k = 0, 1, ... in order.
using PartSliceSink = std::function<void(int64_t k, const std::vector<uint16_t>& slice)>;

/// Generates the part slice by slice into `sink` and returns the truth.
/// @throw ParameterError naming the parameter when a value is out of range
PartTruth generatePartPhantom(const PartPhantomParams& params, const PartSliceSink& sink,
                              Progress* progress = nullptr);

} // namespace flyover
