/// @file mesh_distance.h
/// @brief Distances between two triangle surfaces: one-sided sampled distance and the
///        symmetric Hausdorff distance, with a uniform grid over the target's triangles.
///
/// The distance from a sample point to a surface is exact (closest point on each candidate
/// triangle); the sampling is what makes it an estimate: samples are every vertex of the
/// source plus the centroids of a regular subdivision of each source face into n^2
/// triangles with edges no longer than sampleSpacingMm, so every point of the source lies
/// within sampleSpacingMm / sqrt(3) of a sample and the true one-sided Hausdorff distance is
/// at most the reported maximum plus that much.
#pragma once

#include "surface/mesh_types.h"

#include <cstdint>

namespace flyover {

struct SurfaceDistance {
    double maxMm = 0;     ///< largest sample distance (the one-sided Hausdorff estimate)
    double meanMm = 0;    ///< mean over samples (vertices and face samples alike)
    int64_t samples = 0;
};

/// Distances from points sampled on `from` to the surface of `to` (world mm).
/// @throw ParameterError when sampleSpacingMm is not > 0 or `to` has no faces
SurfaceDistance surfaceDistance(const TriMesh& from, const TriMesh& to, double sampleSpacingMm);

/// Symmetric Hausdorff distance estimate: the larger of the two one-sided maxima.
double hausdorffDistanceMm(const TriMesh& a, const TriMesh& b, double sampleSpacingMm);

} // namespace flyover
