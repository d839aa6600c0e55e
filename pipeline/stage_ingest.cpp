#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runIngest(StudyRun& run, Progress* progress)
{
    IngestReport rep;
    Image3<float> image = readImage(run.opt.ctPath);
    auto grid = ingestImage(image, run.opt.params.ingest, &rep, progress);
    image = {};
    writeGrids(run.path("ct.vdb"), {grid});
    run.state.hu = grid;
    return json{{"voxel_mm", rep.voxelMm},
                {"active_voxels", rep.activeVoxels},
                {"memory_bytes", rep.memoryBytes},
                {"file_bytes", static_cast<int64_t>(fs::file_size(run.path("ct.vdb")))},
                {"input_size", rep.inputSize},
                {"input_spacing_mm", vec3Json(rep.inputSpacingMm)}};
}

} // namespace flyover
