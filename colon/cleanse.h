/// @file cleanse.h
/// @brief Internal to volume/ (used by segmentLumen): electronic cleansing. Finds the
///        tagged fluid that lies under the colon air across an air-fluid level, and the
///        partial-volume rim between the two, so that both join the lumen.
///
/// Fluid candidates are the active voxels above SegmentParams::fluidThresholdHu (only the
/// components with a voxel within LEVEL_REACH_VOXELS of the air are looked at), split into
/// face-connected components (bone and contrast-filled vessels are candidates too). The
/// direction of gravity is the index axis direction g along which most candidates near the
/// kept air have that air "above" them (at v - a g, 1 <= a <= LEVEL_REACH_VOXELS); it is
/// found from the data, so supine, prone and decubitus scans all work, as long as the scan
/// axes are roughly the patient's. A component joins the lumen when it lies under the air
/// across a level: at least half of its voxels near the air (and at least MIN_LEVEL_VOXELS)
/// have air above them along g, and the tops of those columns are flat (standard deviation
/// of their height along g at most MAX_LEVEL_SPREAD_VOXELS). Bone and vessels beside the
/// colon fail the first test, curved contacts the second. The rim is the top voxel of each
/// column of a joined pool that has air above it, and the voxels between it and the air
/// (at most LEVEL_REACH_VOXELS - 1 of them): partial-volume mixtures of air and fluid whose
/// intermediate HU would otherwise read as a wall floating across the lumen.
#pragma once

#include "colon/segment.h"

#include <openvdb/openvdb.h>

#include <vector>

namespace flyover::detail {

/// How far (voxels, along g) air may lie above a fluid voxel across the partial-volume rim.
inline constexpr int LEVEL_REACH_VOXELS = 3;
/// A pool needs at least this many voxels with air above them.
inline constexpr int MIN_LEVEL_VOXELS = 4;
/// Greatest standard deviation (voxels) of the heights of a pool's level columns.
inline constexpr double MAX_LEVEL_SPREAD_VOXELS = 2.0;

struct TaggedFluid {
    openvdb::BoolTree::Ptr joined;          ///< voxels of the joined pools (never null)
    openvdb::BoolTree::Ptr rim;             ///< air-fluid partial-volume voxels (never null; may overlap joined)
    openvdb::BoolTree::Ptr rejected;        ///< candidates near the air that did not join (never null)
    std::vector<openvdb::BoolTree::Ptr> poolTrees;  ///< one per joined pool, as in pools (joined first)
    std::vector<FluidPool> pools;           ///< every candidate component near the air, joined first
    openvdb::Coord gravityStep{0, 0, 0};    ///< index step along g; zero when no level was found
    Vec3d gravityDirection;                 ///< unit world direction of g (or zero)
};

/// @param hu          HU grid (cubic voxels)
/// @param colonAir    the kept air components (index space of hu)
/// @note With params.cleanse false, pools are still found and reported (reason "cleanse
///       off") but none joins.
TaggedFluid findTaggedFluid(const openvdb::FloatGrid& hu, const openvdb::BoolTree& colonAir,
                            const SegmentParams& params);

} // namespace flyover::detail
