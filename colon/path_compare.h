/// @file path_compare.h
/// @brief A path (a centerline) against a reference path of the same colon: per-point distance
///        to the reference, the reference arc each point lies at, and the summary figures the
///        tests and benchmarks report (mean / p95 error, the largest jump along the reference).
///
/// Each path point is matched to its nearest reference point (brute force: reference paths have a
/// few thousand points). A "jump" is the change in matched reference arc between consecutive path
/// points: a path that follows the reference moves along it by about its own step; a shortcut
/// across touching loops jumps by the length of the loop it skipped. LPS millimetres throughout.
#pragma once

#include "volume/vec3.h"

#include <cstddef>
#include <vector>

namespace flyover {

struct PathComparison {
    std::vector<double> errorMm;        ///< per path point: distance to the nearest reference point
    std::vector<double> referenceArcMm; ///< per path point: arc length of that reference point
    double meanErrorMm = 0.0;
    double p95ErrorMm = 0.0;            ///< the 95th percentile (nearest rank below) of errorMm
    double worstJumpMm = 0.0;           ///< the largest |reference arc change| between consecutive points
    std::size_t worstJumpAt = 0;        ///< path index i of that jump (between i-1 and i); 0 when none
    double worstBackwardsMm = 0.0;      ///< the largest step backwards along the reference
};

/// Arc length (mm) from the first point to each point of a polyline.
std::vector<double> arcLengthsMm(const std::vector<Vec3d>& points);

/// Compares path with reference (both non-empty; throws std::invalid_argument otherwise).
PathComparison comparePathToReference(const std::vector<Vec3d>& path, const std::vector<Vec3d>& reference);

} // namespace flyover
