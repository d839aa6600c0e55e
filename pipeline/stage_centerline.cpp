#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "volume/centerline.h"
#include "volume/segment.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runCenterline(StudyRun& run, Progress* progress)
{
    auto sdf = run.sdf();
    // The rectal tube's tip (found by segment) is the rectum hint unless --rectum-mm gave one.
    CenterlineParams params = run.opt.params.centerline;
    bool fromTube = false;
    if (!params.rectumMm)
        if (const auto tip = sdf->getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META)) {
            params.rectumMm = Vec3d{tip->value()[0], tip->value()[1], tip->value()[2]};
            fromTube = true;
        }
    Centerline c = extractCenterline(*sdf, params, progress);
    writeJson(run.path("centerline.json"), centerlineToJson(c));
    run.state.centerline = std::move(c);
    const auto& pts = run.state.centerline->points;
    return json{{"points", pts.size()},
                {"length_mm", run.state.centerline->lengthMm()},
                {"rectum_mm", pts.empty() ? json() : vec3Json(pts.front().positionMm)},
                {"cecum_mm", pts.empty() ? json() : vec3Json(pts.back().positionMm)},
                {"rectum_hint", fromTube ? "rectal tube tip" : (params.rectumMm ? "rectum_mm" : "none")}};
}

} // namespace flyover
