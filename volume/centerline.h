/// @file centerline.h
/// @brief The lumen centerline from the signed distance grid: geodesic farthest endpoints,
///        a minimal path whose cost grows towards the wall, smoothing, uniform resampling.
#pragma once

#include "volume/centerline_types.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <optional>

namespace flyover {

struct CenterlineParams {
    double stepMm = 1.0;            ///< arc-length step of the output (mm, > 0)
    double wallPenalty = 2.0;       ///< exponent p of the cost 1/D^p (D: distance to wall, mm)
    double smoothingMm = 4.0;       ///< Gaussian smoothing sigma along the path (mm, >= 0)
    std::optional<Vec3d> rectumMm;  ///< overrides the rectum endpoint (LPS mm)
    static constexpr int VERSION = 1;
};

/// @param sdf  lumen signed distance grid in world mm, negative inside the lumen
/// @throw InputError when the lumen is empty
Centerline extractCenterline(const openvdb::FloatGrid& sdf, const CenterlineParams& params,
                             Progress* progress = nullptr);

} // namespace flyover
