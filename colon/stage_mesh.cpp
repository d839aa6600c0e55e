#include "colon/study_run.h"

#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "colon/uncut_lumen.h"
#include "surface/lumen_surface.h"

#include <algorithm>
#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

/// The manifest lists at most this many components (largest first); the totals cover all.
constexpr std::size_t MAX_LISTED_COMPONENTS = 20;

json componentJson(const MeshComponent& c)
{
    return json{{"faces", c.faces},
                {"genus", c.genus},
                {"boundary_loops", c.boundaryLoops},
                {"area_mm2", c.areaMm2},
                {"enclosed_volume_mm3", c.enclosedVolumeMm3},
                {"nesting_depth", c.nestingDepth},
                {"inward_volume_sign", c.hasInwardVolumeSign()}};
}

/// The mesh stage's report; `besideCut`: the mesh was made beside the segment stage's contact cut.
json meshReportJson(const LumenSurfaceReport& r, const MeshParams& params, bool besideCut)
{
    const MeshCheck& c = r.check;
    json components = json::array();
    for (std::size_t i = 0; i < std::min(c.componentList.size(), MAX_LISTED_COMPONENTS); ++i)
        components.push_back(componentJson(c.componentList[i]));
    const MeshStats& e = r.extraction;
    return json{
        // Meshed beside the segment stage's contact cut (which removed nothing), or here.
        {"made_beside_contact_cut", besideCut},
        // The final surface (surface.ply).
        {"vertices", c.vertices},
        {"edges", c.edges},
        {"faces", c.faces},
        {"components", c.components},
        {"closed_components", c.closedComponents},
        {"genus", c.genus},
        {"boundary_loops", c.boundaryLoops},
        {"boundary_edges", c.boundaryEdges},
        {"non_manifold_vertices", c.nonManifoldVertices},
        {"degenerate_faces", c.degenerateFaces},
        {"area_mm2", c.areaMm2},
        {"enclosed_volume_mm3", c.enclosedVolumeMm3},
        {"component_list", components},
        // Orientation, checked two ways: per face against the level set's gradient, and per
        // component by the sign of its enclosed volume.
        {"inward_fraction", r.orientation.inwardFraction()},
        {"outward_faces", r.orientation.outward},
        {"faces_without_gradient", r.orientation.noGradient},
        {"misoriented_components", c.misorientedComponents},
        {"sound", r.isSound()},
        {"extraction",
         {{"vertices", e.vertices},
          {"faces", e.faces},
          {"dropped_faces", e.droppedFaces},
          {"non_manifold_edges", e.nonManifoldEdges},
          {"orientation_conflicts", e.orientationConflicts},
          {"degenerate_repairs", e.degenerateRepairs},
          {"removed_degenerate_faces", e.removedDegenerateFaces},
          {"area_mm2", r.rawAreaMm2},
          {"enclosed_volume_mm3", r.rawVolumeMm3},
          {"roughness_deg", r.rawRoughnessDeg},
          {"seconds", r.extractSeconds}}},
        {"smoothing",
         {{"method", params.smoothMethod},
          {"iterations", params.smoothIterations},
          {"pass_band", params.smoothPassBand},
          {"max_displacement_mm", r.smoothing.maxDisplacementMm},
          {"rms_displacement_mm", r.smoothing.rmsDisplacementMm},
          {"fixed_vertices", r.smoothing.fixedVertices},
          {"restored_vertices", r.smoothingRestoredVertices},
          {"enclosed_volume_mm3", r.smoothedVolumeMm3},
          {"volume_change_fraction", r.smoothingVolumeChange},
          {"roughness_deg", r.smoothedRoughnessDeg},
          {"seconds", r.smoothSeconds}}},
        {"decimation",
         {{"faces_before", r.decimation.facesBefore},
          {"faces_after", r.decimation.facesAfter},
          {"collapses", r.decimation.collapses},
          {"reached_target", r.decimation.reachedTarget},
          {"max_error_mm", r.decimationMaxErrorMm},
          {"hausdorff_mm", r.decimationHausdorffMm},
          {"seconds", r.decimateSeconds}}},
        {"check_seconds", r.checkSeconds},
        // The checks of the final mesh were made behind the next stages (the first pair).
        {"checked_behind", r.finalChecksPending}};
}

} // namespace

json runMesh(StudyRun& run, Progress* progress)
{
    auto sdf = run.sdf();
    const MeshParams& params = run.opt.params.mesh;
    LumenSurfaceReport r;
    // The checks of the final mesh are left to be made behind the next stages (before the
    // stage's record is written) when its artifacts are written behind.
    DeferredWrites* behind = DeferredWrites::active();
    // The early node's mesh of this very lumen, made beside the segment stage's contact cut,
    // when it made one and the cut removed nothing.
    const std::shared_ptr<UncutLumen> uncut = run.state.uncutLumen;
    const bool besideCut = uncut && uncut->isFinal() && uncut->mesh.has_value();
    if (besideCut) {
        run.state.mesh = std::move(uncut->mesh);
        uncut->mesh.reset();
        r = uncut->meshReport;
    } else {
        run.state.mesh = makeLumenSurface(*sdf, params, &r, progress, true, behind != nullptr);
    }
    // The render scenes' arrays and normals from the mesh in memory, beside the writing and
    // hashing of surface.ply (the early node "render:surface-arrays").
    run.handOn("mesh:mesh");
    writeMesh(run.path("surface.ply"), *run.state.mesh);
    if (r.finalChecksPending && !behind) checkLumenSurface(*run.state.mesh, *sdf, r);
    if (r.finalChecksPending) {
        // Made in the write-behind's commit, after the first pair; reads the mesh and the level
        // set beside the render (which reads them too); the run keeps both until its end.
        const TriMesh* m = &*run.state.mesh;
        behind->addReportPart([m, sdf, r, params, besideCut](json& report) mutable {
            checkLumenSurface(*m, *sdf, r);
            report = meshReportJson(r, params, besideCut);
            report["checked_behind"] = true;
        });
    }
    return meshReportJson(r, params, besideCut);
}

} // namespace flyover
