#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "volume/segment.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runSegment(StudyRun& run, Progress* progress)
{
    if (!run.state.hu)
        run.state.hu = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(run.path("ct.vdb"), "ct_hu"));
    LumenSegmentation seg = segmentLumen(*run.state.hu, run.opt.params.segment, progress);
    writeGrids(run.path("lumen.vdb"), {seg.mask, seg.sdf});
    run.state.sdf = seg.sdf;
    json comps = json::array();
    for (const auto& c : seg.components)
        comps.push_back(json{{"volume_ml", c.volumeMl},    {"mean_hu", c.meanHu},
                             {"centroid_mm", vec3Json(c.centroidMm)},
                             {"min_mm", vec3Json(c.minMm)}, {"max_mm", vec3Json(c.maxMm)},
                             {"kept", c.kept},             {"reason", c.reason}});
    return json{{"lumen_volume_ml", seg.lumenVolumeMl}, {"components", comps}};
}

} // namespace flyover
