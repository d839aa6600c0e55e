/// @file phantom.h
/// @brief Synthetic abdominal CT phantoms with ground truth (design.md "Data").
///
/// Outside air, a body with a fat layer and a bone (spine), two lungs, small-bowel gas
/// pockets away from the colon, and a colon-shaped air tube (rectum, sigmoid, descending,
/// transverse, ascending, cecum; radius about 12-28 mm) with haustral folds and polyps of
/// 3-12 mm radius, some between folds; partial-volume blur and Gaussian noise; int16 HU.
/// Deterministic for a given (size, seed). All positions are LPS world millimetres.
#pragma once

#include "volume/image.h"
#include "volume/vec3.h"

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

enum class PhantomSize { Small, Medium, Full };

/// @throw ParameterError for a name other than small, medium, full.
PhantomSize parsePhantomSize(const std::string& name);
const char* phantomSizeName(PhantomSize size);

struct PhantomParams {
    PhantomSize size = PhantomSize::Small;
    uint64_t seed = 1;
    double noiseHu = 15.0;   ///< standard deviation of the added Gaussian noise (HU)
};

struct PhantomPolyp {
    Vec3d centerMm;          ///< world LPS mm
    double radiusMm = 0;
    double arcMm = 0;        ///< arc length of the nearest true centerline point from the rectum
    Vec3d outwardDir;        ///< unit direction from the centerline towards the polyp's base
    bool betweenFolds = false;
};

struct PhantomTruth {
    std::vector<Vec3d> centerlineMm;   ///< ordered rectum -> cecum
    std::vector<double> radiusMm;      ///< lumen radius per centerline point (fold-free)
    std::vector<std::string> segment;  ///< anatomical segment name per point
    std::vector<PhantomPolyp> polyps;
    double lumenVolumeMl = 0;          ///< volume of the true lumen mask
};

struct Phantom {
    Image3<int16_t> ct;          ///< HU
    Image3<uint8_t> truthLumen;  ///< 1 inside the true colon lumen (at voxel centres)
    PhantomTruth truth;
};

Phantom makePhantom(const PhantomParams& params);

} // namespace flyover
