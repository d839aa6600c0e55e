/// @file polyp_detect.h
/// @brief Polyp candidates on the lumen's level set: cap-shaped patches of the wall, by the
///        shape index and curvedness of the surface (Yoshida and Näppi, RadioGraphics 2002),
///        measured against the surrounding wall.
///
/// The steps, each a function in polyp_detect.cpp (docs/method.md, "Polyp candidates"):
/// 1. surface voxels: the level set's voxels within half a voxel of the wall.
/// 2. shape: at each, a Gaussian-weighted quadric fitted to the level set over 5 x 5 x 5
///    voxels gives the normal and the two principal curvatures of the wall seen from the
///    lumen (positive: bulging into it); from them the shape index SI in [0, 1] (1: a cap,
///    0.75: a ridge, 0.5: a saddle, 0.25: a rut such as the lumen's own wall, 0: a cup) and the
///    curvedness CV (1/mm).
/// 3. regions: voxels with SI >= shapeIndexSeed and CV in range seed regions that grow over
///    face-and-corner neighbours with SI >= shapeIndexGrow (hysteresis).
/// 4. measures: each region's size (its largest diameter), height above the plane of the
///    surrounding wall, volume, elongation and morphology.
/// 5. rules: regions too small, too low, elongated, going on as a ridge (folds and their
///    ends) or a small cap on a broad swelling are dropped, with the reason.
#pragma once

#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <cstddef>
#include <map>
#include <string>
#include <vector>

namespace flyover {

struct PolypParams {
    bool enabled = true;               ///< false: the stage writes an empty candidate list
    double shapeIndexSeed = 0.9;       ///< a region starts at a voxel this cap-like or more
    double shapeIndexGrow = 0.8;       ///< and grows over voxels this cap-like or more
    double curvednessMinPerMm = 0.04;  ///< seeds bend at least this much (1/mm; a 25 mm cap)
    double curvednessMaxPerMm = 0.8;   ///< and at most this much (1/mm; finer is noise)
    double minSizeMm = 5.0;            ///< candidates are at least this wide (mm)
    double minHeightMm = 1.5;          ///< and rise at least this far above the wall (mm)
    double maxElongation = 2.2;        ///< longest / shortest extent on the wall (folds are longer)
    /// The cap covers at least this share of the footprint's disc (a polyp is a dome; a small
    /// bump on a broad swelling of the wall is not).
    double minCapFraction = 0.35;
    int maxCandidates = 12;            ///< the best this many by score are kept
    bool images = true;                ///< an OST pair and, with a CT, three CT crops per candidate
    double cropMm = 60.0;              ///< side of the CT crops (mm)
    static constexpr int VERSION = 1;
};

/// One region that passed the rules, or was dropped by one.
struct PolypRegion {
    Vec3d centroidMm;      ///< mean of the region's wall points (LPS mm): inside a convex cap
    Vec3d apexMm;          ///< the region's point farthest above the surrounding wall
    Vec3d upDir;           ///< unit direction from the wall into the lumen (mean normal)
    Vec3d baseCentreMm;    ///< the centroid's foot on the plane of the surrounding wall
    Vec3d planeNormal;     ///< unit normal of that plane, into the lumen
    double sizeMm = 0;     ///< largest distance between two of its wall points
    double heightMm = 0;   ///< apex above the plane of the surrounding wall
    double volumeMm3 = 0;  ///< tissue above that plane within the region's reach
    double areaMm2 = 0;
    double elongation = 1;
    double meanShapeIndex = 0, meanCurvednessPerMm = 0;
    double rimHeightMm = 0;  ///< the region's rim above the surrounding wall (a stalk lifts it)
    /// How far beyond its rim the wall stays above 70% of its height (a fold's end goes on
    /// along the fold; a polyp's cap falls to the wall), mm.
    double ridgeReachMm = 0;
    double capFraction = 0;   ///< the cap's area over the disc of the footprint's size
    double crestWidthMm = 0;  ///< the widest such ridge 3-5 mm beyond its footprint, mm
    std::string morphology;  ///< sessile | pedunculated | flat
    double score = 0;        ///< 0..1
    std::size_t voxels = 0;
    std::string dropped;     ///< "" = kept; else the rule that dropped it
};

/// Shape of the wall at one surface voxel.
struct WallShape {
    Vec3d pointMm;         ///< the voxel centre moved onto the fitted wall
    Vec3d normal;          ///< unit, into the lumen
    double shapeIndex = 0;
    double curvednessPerMm = 0;
};

/// Step 2 at one index point of the level set (mm values, negative inside the lumen).
WallShape wallShapeAt(const openvdb::FloatGrid& sdf, const openvdb::Coord& ijk);

struct PolypDetection {
    std::vector<PolypRegion> candidates;  ///< kept, best score first
    std::vector<PolypRegion> dropped;     ///< with the rule in `dropped`
    std::size_t surfaceVoxels = 0, seedVoxels = 0, regions = 0;
    std::map<std::string, std::size_t> droppedBy;
    double seconds = 0;
};

/// Steps 1-5 on the lumen's level set (cubic voxels, mm, negative inside).
/// @throw ParameterError for parameters out of range.
PolypDetection detectPolyps(const openvdb::FloatGrid& sdf, const PolypParams& params);

/// The voxels of a region's body: tissue (level set > 0) above the plane of the surrounding
/// wall, within half its size and a voxel of the base centre. Its volume is their count.
std::vector<openvdb::Coord> polypBodyVoxels(const openvdb::FloatGrid& sdf, const PolypRegion& region);

/// The shape index of principal curvatures c1 >= c2 (lumen side positive): 1 cap, 0 cup.
double shapeIndexOf(double c1, double c2);

/// @throw ParameterError naming the first parameter out of range.
void validatePolypParams(const PolypParams& params);

} // namespace flyover
