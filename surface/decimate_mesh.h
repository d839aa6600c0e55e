/// @file decimate_mesh.h
/// @brief Incremental decimation by halfedge collapses (OpenMesh's decimater): a quadric
///        error priority, a normal-flip guard, and optionally a bound on the distance from
///        the original vertices to the decimated surface.
///
/// Collapses keep the topology (OpenMesh's link condition: no new non-manifold element,
/// no change of genus or component count) and boundary loops stay boundary loops. The
/// normal-flip guard refuses a collapse that turns any surrounding face's normal by more
/// than maxNormalDeviationDeg, so the inward orientation survives. Vertices keep their
/// positions (a collapse moves one vertex onto its neighbour): no new points are invented.
#pragma once

#include "surface/mesh_types.h"
#include "volume/progress.h"

#include <cstdint>
#include <functional>

namespace flyover {

struct DecimateParams {
    int64_t targetFaces = 0;             ///< stop at this many faces (0 = no budget)
    /// Largest distance (world mm) from any vertex of the input mesh to the decimated surface
    /// (OpenMesh ModHausdorffT, binary). 0 = no bound.
    double maxErrorMm = 0.0;
    double maxNormalDeviationDeg = 45.0; ///< normal-flip guard per collapse, in (0, 180]
    /// Optional guard: a collapse is refused when any triangle it reshapes fails this test
    /// (corners a, b, c in winding order; e.g. LumenSideTest::isInward). Called serially.
    std::function<bool(const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b, const OpenMesh::Vec3d& c)> acceptTriangle;
};

struct DecimateReport {
    int64_t facesBefore = 0;
    int64_t facesAfter = 0;
    int64_t collapses = 0;
    bool reachedTarget = false;  ///< a budget was given and met (else no collapse passed the guards)
};

/// Decimates `mesh` in place until targetFaces is reached or no collapse passes the
/// error bound and the flip guard. Neither a budget nor a bound: the mesh is left unchanged.
/// @note the mesh is garbage-collected afterwards: vertex and face handles are renumbered,
///       and the status and normal attributes the decimater needs are released again.
/// @throw ParameterError for a negative budget or bound, or a deviation outside (0, 180]
void decimateMesh(TriMesh& mesh, const DecimateParams& params, DecimateReport* report = nullptr,
                  Progress* progress = nullptr);

} // namespace flyover
