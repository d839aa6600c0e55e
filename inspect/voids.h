/// @file voids.h
/// @brief Internal voids (pores, cracks) of a solid part in an industrial CT grid: threshold
///        (Otsu or given) -> material; air connected to the grid border -> outside air (a
///        through bore, a crack open to the surface); the remaining air components are the
///        internal voids, each measured (volume, equivalent diameter, extent, sphericity,
///        centroid, distance to the outer surface) and classified as pore or crack.
///        Sparse OpenVDB grids throughout, so that 1024^3 parts fit in memory.
#pragma once

#include "volume/mask_components.h"
#include "volume/progress.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace flyover {

struct VoidParams {
    double threshold = std::numeric_limits<double>::quiet_NaN(); ///< material >= threshold; NaN = Otsu
    double minDiameterVoxels = 2.0;  ///< voids with equivalent diameter below this are counted, not listed
    static constexpr int VERSION = 1;
};

struct VoidInfo {
    int id = 0;                       ///< 1..N, ordered by volume, largest first
    std::string kind;                 ///< "pore" or "crack"
    double volumeMm3 = 0, equivalentDiameterMm = 0, maxExtentMm = 0, sphericity = 0;
    Vec3d centroidLps;                ///< LPS mm
    double distanceToSurfaceMm = 0;   ///< centroid -> nearest outer surface of the part
    int64_t voxels = 0;
};

struct PartAnalysis {
    double threshold = 0; std::string thresholdSource;   ///< "otsu" or "given"
    openvdb::BoolGrid::Ptr material;     ///< material voxels, same transform as the CT grid
    openvdb::BoolGrid::Ptr outsideAir;   ///< air connected to the border / open cavities
    openvdb::Int32Grid::Ptr voidLabels;  ///< voxel -> VoidInfo::id for listed voids, background 0
    std::vector<VoidInfo> voids;
    int64_t smallVoidCount = 0; double smallVoidVolumeMm3 = 0;
    double materialVolumeMm3 = 0, voidVolumeMm3 = 0 /*all internal voids incl. small*/, porosityPercent = 0;
};

/// @throw InputError (volume/error.h) naming `sourceName` when there is no material, all material, ...
PartAnalysis analysePart(const openvdb::FloatGrid& ct, const VoidParams& params,
                         const std::string& sourceName, Progress* progress = nullptr);

/// Largest distance (voxels) between two of the given voxel centres (index coordinates):
/// exact over the candidates when there are at most 3000 of them, else over the voxels that
/// are extreme along 1024 directions spread over the sphere (relative error below 0.3%).
/// Pass the voxels of a region's boundary (the farthest pair lies on it). 0 for < 2 voxels.
double maxVoxelDistance(const std::vector<openvdb::Vec3d>& voxels);


/// Equivalent diameter (6 V / pi)^(1/3) of a volume V (any unit^3 -> unit).
double equivalentDiameter(double volume);

} // namespace flyover
