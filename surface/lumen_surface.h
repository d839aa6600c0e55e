/// @file lumen_surface.h
/// @brief The mesh stage's work in one call: lumen level set -> inward-oriented triangle
///        mesh (extractSurface), Taubin smoothing, optional decimation, then the checks
///        that make one-sided transparency trustworthy, all measured for the manifest.
///
/// Order and why: volumeToMesh places vertices on the zero crossing; the mesh smoother then
/// removes the voxel-scale ripple without moving low frequencies (polyps, folds, the
/// enclosed volume); decimation comes last so that it simplifies the smooth surface, not
/// the staircase. Orientation is checked twice on the final mesh: per face against the
/// level set's gradient, and per component by the sign of its enclosed volume.
///
/// Guards: smoothing and decimation may not turn a face away from the lumen. After smoothing,
/// the corners of any face that no longer points into the lumen go back to their extracted
/// positions (counted in smoothingRestoredVertices); decimation refuses such collapses.
/// Beyond that nothing is repaired: a failed check is counted in the report (the caller
/// decides). No files are written.
///
/// Defaults (MeshParams) and the measurements behind them, full-size phantom (seed 1, 0.78 mm
/// voxels, 880k triangles) unless said otherwise:
/// - Smoothing: Taubin, 40 iterations, pass band 0.05. Enclosed volume +0.04%; the ten truth
///   polyps (3-11.6 mm) keep 98-102% of their unsmoothed height; on a voxel-mask (staircase)
///   sphere of 20 voxels radius the mean normal error drops from 12.3 to 2.9 degrees at +0.17%
///   volume. Level-set smoothing before meshing (OpenVDB LevelSetFilter) was measured and not
///   chosen: mean curvature x2 shrinks the 3 mm polyp to 94% of its height (x5: 84.5%), one
///   Gaussian pass to 74% (volume -0.6%), and each costs 10-30 s against ~1 s here.
/// - Decimation: off. Embree traces 1M triangles at full speed, so halving costs more
///   (OpenMesh's serial decimater, ~15 s) than it saves. When asked for, half the faces
///   measured: symmetric Hausdorff 0.065 mm (0.08 voxel), volume and polyp heights unchanged
///   to 0.01%. A vertex error bound of 0.1 voxel keeps ~5% of the faces but its symmetric
///   distance is larger (0.3 mm): the bound covers the extracted vertices only.
#pragma once

#include "surface/decimate_mesh.h"
#include "surface/extract_surface.h"
#include "surface/mesh_checks.h"
#include "surface/smooth_mesh.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace flyover {

struct LumenSurfaceReport {
    MeshStats extraction;         ///< the raw volumeToMesh surface
    double rawAreaMm2 = 0;
    double rawVolumeMm3 = 0;      ///< capped signed volume of the raw mesh (as MeshCheck)
    double rawRoughnessDeg = 0;   ///< meanDihedralAngleDeg before smoothing

    SmoothReport smoothing;
    /// Vertices the orientation guard put back to their extracted position because a face
    /// around them no longer pointed into the lumen after smoothing.
    int64_t smoothingRestoredVertices = 0;
    double smoothedVolumeMm3 = 0;
    double smoothedRoughnessDeg = 0;
    /// (smoothed - raw) / raw enclosed volume; 0 without smoothing.
    double smoothingVolumeChange = 0;

    DecimateReport decimation;
    double decimationMaxErrorMm = 0;     ///< the bound used (mm; 0 = none)
    /// Symmetric Hausdorff distance between the surface before and after decimation (samples
    /// every half voxel, see mesh_distance.h); 0 when no decimation ran or it was not measured.
    double decimationHausdorffMm = 0;

    MeshCheck check;                ///< the final mesh
    FaceOrientation orientation;    ///< the final mesh against the level set

    double extractSeconds = 0, smoothSeconds = 0, decimateSeconds = 0, checkSeconds = 0;

    /// Whether smoothing ran (the smoothed measures are then those of the mesh after it).
    bool smoothed = false;
    /// The checks of the final mesh (check, orientation, the smoothed measures) are still to
    /// be made by checkLumenSurface(): makeLumenSurface() was asked to leave them.
    bool finalChecksPending = false;
    /// While the final checks are pending: `orientation` is already that of the final mesh
    /// (counted by the smoothing guard, restoreNonInwardFaces), so checkLumenSurface() keeps it.
    bool orientationCounted = false;
    /// While the final checks are pending after smoothing: the extracted vertex positions
    /// (indexed by vertex), for the raw measures (rawAreaMm2, rawVolumeMm3, rawRoughnessDeg),
    /// which are then pending too. Released by checkLumenSurface().
    std::shared_ptr<const std::vector<TriMesh::Point>> extractedPoints;
    /// While the final checks are pending: volumeToMesh's triangle soup, whose edge checks
    /// (extraction.nonManifoldEdges, orientationConflicts) are then pending too. Released by
    /// checkLumenSurface().
    std::shared_ptr<const TriangleSoup> extractedTriangles;

    /// Every face inward, no outward component, manifold (no refused face, no edge of more
    /// than two faces, no pinched vertex), consistently wound, no degenerate face.
    bool isSound() const
    {
        return orientation.outward == 0 && orientation.noGradient == 0 && orientation.degenerate == 0 &&
               check.misorientedComponents == 0 && check.isManifold() && check.degenerateFaces == 0 &&
               extraction.droppedFaces == 0 && extraction.nonManifoldEdges == 0 &&
               extraction.orientationConflicts == 0;
    }
};

/// @param sdf  lumen level set (world mm, negative inside)
/// @param measureDecimationError  compute decimationHausdorffMm (costs about as much as the
///        decimation itself)
/// @param deferFinalChecks  leave the checks of the final mesh (report->check, orientation,
///        smoothedVolumeMm3, smoothedRoughnessDeg, smoothingVolumeChange) to a later call of
///        checkLumenSurface(), so that the mesh can be used first (the pipeline renders the
///        first pair meanwhile); report->finalChecksPending says whether they were
///        left. The raw mesh's measures (rawAreaMm2, rawVolumeMm3, rawRoughnessDeg) are left
///        too (the extracted positions are kept in report->extractedPoints meanwhile), and so
///        are the extraction's soup edge checks (its triangles kept in
///        report->extractedTriangles). Ignored
///        when decimation is asked for (the smoothed measures are then taken before it). The
///        mesh is the same either way. It also leaves out the extraction's
///        surface-wide stats (report->extraction keeps its counts only: extractSurface's
///        surfaceStats), which no report of the pipeline shows.
/// @throw ParameterError for invalid params (names the field), InputError when the level set
///        has no zero crossing
TriMesh makeLumenSurface(const openvdb::FloatGrid& sdf, const MeshParams& params,
                         LumenSurfaceReport* report = nullptr, Progress* progress = nullptr,
                         bool measureDecimationError = true, bool deferFinalChecks = false);

/// The checks makeLumenSurface() left (report.finalChecksPending) on the mesh it returned and
/// the level set it meshed; fills `report` as makeLumenSurface() would have, and adds their
/// time to checkSeconds. Reads `mesh` and `sdf` only: safe beside other readers. Does nothing
/// when no check is pending.
void checkLumenSurface(const TriMesh& mesh, const openvdb::FloatGrid& sdf, LumenSurfaceReport& report);

/// The smoothing guard: every face of `mesh` that does not point into the lumen (e.g. a
/// sliver a smoother tilted past the surface's tangent plane) gets its corners back at their
/// `extracted` positions (indexed by vertex); the faces around them are checked again, until
/// every face is inward or nothing is left to restore (the extracted mesh is the fixed point).
/// @param orientation  if given, receives checkFaceOrientation(mesh, sdf) of the mesh as it is
///        left (the first pass's counts, updated for every face checked again): the same
///        numbers, without a second pass over every face
/// @return the number of vertices restored
int64_t restoreNonInwardFaces(TriMesh& mesh, const std::vector<TriMesh::Point>& extracted,
                              const openvdb::FloatGrid& sdf, FaceOrientation* orientation = nullptr);

/// Checks MeshParams' ranges. @throw ParameterError naming the field and the value
void validateMeshParams(const MeshParams& params);

} // namespace flyover
