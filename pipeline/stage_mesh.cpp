#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "surface/extract_surface.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runMesh(StudyRun& run, Progress* progress)
{
    auto sdf = run.sdf();
    MeshStats st;
    TriMesh mesh = extractSurface(*sdf, run.opt.params.mesh, &st, progress);
    writeMesh(run.path("surface.ply"), mesh);
    run.state.mesh = std::move(mesh);
    return json{{"vertices", st.vertices},          {"faces", st.faces},
                {"components", st.components},      {"boundary_edges", st.boundaryEdges},
                {"dropped_faces", st.droppedFaces}, {"area_mm2", st.areaMm2},
                {"enclosed_volume_mm3", st.enclosedVolumeMm3},
                {"inward_fraction", st.inwardFraction}};
}

} // namespace flyover
