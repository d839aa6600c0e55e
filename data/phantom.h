/// @file phantom.h
/// @brief Synthetic abdominal CT phantoms with ground truth (design.md "Data").
///
/// Outside air, a body with a fat layer and a bone (spine), two lungs, small-bowel gas
/// pockets away from the colon, and a colon-shaped air tube (rectum, sigmoid, descending,
/// transverse, ascending, cecum; radius about 12-28 mm) with haustral folds and polyps of
/// 3-12 mm radius, some between folds; partial-volume blur and Gaussian noise; int16 HU.
/// Deterministic for a given (size, seed, variant). All positions are LPS world millimetres.
///
/// Variants (off by default; the default phantom is byte-identical with or without them
/// compiled in, because they draw from their own random streams):
/// - fluid: tagged fluid (+300..+600 HU, one value per pool) fills the dependent part of
///   the lumen in three pools (rectum, descending, ascending + cecum): the patient lies
///   supine, so fluid lies posterior (+y) of a flat air-fluid level (a plane y = levelYMm),
///   with a one-voxel partial-volume ramp at the level. The truth lumen is air + fluid.
/// - collapse: one or two stretches of 20-40 mm of the sigmoid have no lumen (soft tissue
///   inside the wall), so the colon falls into 2 or 3 pieces; the truth centerline stays
///   the full path and the truth lists the collapsed arc ranges.
/// - colon = false: no colon at all (body, lungs, small-bowel gas, spine): a scan on which
///   segmentation must refuse with a clear message.
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
    bool fluid = false;      ///< tagged fluid pools with flat air-fluid levels
    bool collapse = false;   ///< one or two collapsed stretches of the sigmoid
    bool colon = true;       ///< false: no colon (lungs, gas pockets, body only)
};

struct PhantomPolyp {
    Vec3d centerMm;          ///< world LPS mm
    double radiusMm = 0;
    double arcMm = 0;        ///< arc length of the nearest true centerline point from the rectum
    Vec3d outwardDir;        ///< unit direction from the centerline towards the polyp's base
    bool betweenFolds = false;
};

/// A stretch of the colon with no lumen: arc lengths from the rectum end of the centerline.
struct PhantomCollapse {
    double arcStartMm = 0;
    double arcEndMm = 0;
};

/// A pool of tagged fluid: the lumen points whose nearest centerline arc is in
/// [arcStartMm, arcEndMm] and that lie posterior of the level (y > levelYMm) hold fluid.
struct PhantomFluidPool {
    double arcStartMm = 0;
    double arcEndMm = 0;
    double levelYMm = 0;     ///< LPS y of the flat air-fluid level (mm)
    double hu = 0;           ///< fluid value (HU)
};

struct PhantomTruth {
    std::vector<Vec3d> centerlineMm;   ///< ordered rectum -> cecum
    std::vector<double> radiusMm;      ///< lumen radius per centerline point (fold-free)
    std::vector<std::string> segment;  ///< anatomical segment name per point
    std::vector<PhantomPolyp> polyps;
    std::vector<PhantomCollapse> collapsed;   ///< sorted by arc; empty unless params.collapse
    std::vector<PhantomFluidPool> fluidPools; ///< sorted by arc; empty unless params.fluid
    double lumenVolumeMl = 0;          ///< volume of the true lumen mask (air and fluid)
    double fluidVolumeMl = 0;          ///< part of it whose voxel centres hold fluid
};

struct Phantom {
    Image3<int16_t> ct;          ///< HU
    Image3<uint8_t> truthLumen;  ///< 1 inside the true colon lumen, air or fluid (at voxel centres)
    PhantomTruth truth;
};

Phantom makePhantom(const PhantomParams& params);

} // namespace flyover
