/// @file smooth_mesh.h
/// @brief Taubin's lambda|mu smoothing (Taubin 1995, "A signal processing approach to fair
///        surface design"): a low-pass filter on vertex positions that removes the voxel
///        staircase and noise without the shrinkage of plain Laplacian smoothing.
///
/// Each iteration is a shrinking step p += lambda L(p) followed by an inflating step
/// p += mu L(p) (mu < -lambda < 0), with the umbrella operator L(p) = mean(neighbours) - p.
/// Surface frequencies k below the pass band k_PB = 1/lambda + 1/mu pass almost unchanged,
/// higher ones (the staircase, about one voxel long) are damped. Boundary vertices and
/// non-manifold vertices stay where they are, so open loops do not creep. Connectivity
/// (hence topology and face orientation) is unchanged; a face can still fold over where
/// the filter moves vertices more than the faces are wide, which the mesh checks report.
#pragma once

#include "surface/mesh_types.h"
#include "volume/progress.h"

namespace flyover {

struct TaubinParams {
    int iterations = 40;       ///< lambda|mu pairs, >= 0 (0 leaves the mesh unchanged)
    double passBand = 0.05;    ///< k_PB in (0, 1): frequencies below it pass unchanged
    double lambda = 0.5;       ///< shrinking step weight in (0, 1)

    /// mu from lambda and the pass band: 1/lambda + 1/mu = k_PB.
    double mu() const { return 1.0 / (passBand - 1.0 / lambda); }
};

/// How far the smoothing moved the vertices (world mm).
struct SmoothReport {
    double maxDisplacementMm = 0;
    double rmsDisplacementMm = 0;
    int64_t fixedVertices = 0;   ///< boundary and non-manifold vertices, left in place
};

/// Smooths `mesh` in place. Jacobi updates, parallel over tiles of vertices a few steps at a
/// time (each vertex's arithmetic is the plain rule's: the result is the same bit for bit and
/// does not depend on the thread count).
/// @throw ParameterError for iterations < 0, passBand outside (0, 1), lambda outside (0, 1)
void smoothMeshTaubin(TriMesh& mesh, const TaubinParams& params, SmoothReport* report = nullptr,
                      Progress* progress = nullptr);

} // namespace flyover
