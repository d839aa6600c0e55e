/// @file segment.h
/// @brief Colon lumen segmentation on the sparse HU grid.
///
/// Air candidates (HU < airThresholdHu) among the active voxels are split into connected
/// components; components touching the grid border, lungs (parenchyma HU and superior
/// position) and small gas pockets are dropped; the remaining large components are the
/// lumen. The lumen surface is then placed at the partial-volume midpoint (surfaceIsoHu)
/// of the HU field near the kept air, and redistanced into a signed distance grid.
#pragma once

#include "volume/progress.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace flyover {

struct SegmentParams {
    double airThresholdHu = -800.0;   ///< air candidates are below this (HU)
    double surfaceIsoHu = -500.0;     ///< lumen surface: partial-volume midpoint air/wall (HU)
    double minComponentMl = 20.0;     ///< air components smaller than this are dropped (mL)
    double lungMinMeanHu = -930.0;    ///< a component whose mean HU is above this is lung (HU)
    double keepFraction = 0.05;       ///< keep components >= this fraction of the largest kept
    int bandVoxels = 3;               ///< exterior narrow band of the level set (voxels)
    static constexpr int VERSION = 1;
};

/// What happened to one connected air component.
struct AirComponent {
    double volumeMl = 0;
    double meanHu = 0;
    Vec3d centroidMm, minMm, maxMm;  ///< world LPS mm
    bool kept = false;
    std::string reason;              ///< "colon", "lung", "small", "border", "fraction"
};

struct LumenSegmentation {
    openvdb::BoolGrid::Ptr mask;   ///< lumen voxels (active = inside); name "lumen_mask"
    openvdb::FloatGrid::Ptr sdf;   ///< signed distance (mm), negative inside; name "lumen_sdf"
    std::vector<AirComponent> components;
    double lumenVolumeMl = 0;
};

/// @throw InputError when no component qualifies as colon lumen (message lists what was found).
LumenSegmentation segmentLumen(const openvdb::FloatGrid& hu, const SegmentParams& params,
                               Progress* progress = nullptr);

} // namespace flyover
