#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "volume/centerline.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runCenterline(StudyRun& run, Progress* progress)
{
    auto sdf = run.sdf();
    Centerline c = extractCenterline(*sdf, run.opt.params.centerline, progress);
    writeJson(run.path("centerline.json"), centerlineToJson(c));
    run.state.centerline = std::move(c);
    const auto& pts = run.state.centerline->points;
    return json{{"points", pts.size()},
                {"length_mm", run.state.centerline->lengthMm()},
                {"rectum_mm", pts.empty() ? json() : vec3Json(pts.front().positionMm)},
                {"cecum_mm", pts.empty() ? json() : vec3Json(pts.back().positionMm)}};
}

} // namespace flyover
