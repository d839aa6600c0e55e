// The ingest shared by every application's stage graph: the scan into an isotropic grid and ct.vdb.
#include "pipeline/ingest_to_vdb.h"

#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "pipeline/grid_write.h"
#include "volume/image_io.h"
#include "volume/ingest.h"
#include "volume/vec3.h"

#include <sys/resource.h>

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

json matrixJson(const Mat3d& m)
{
    json rows = json::array();
    for (const auto& r : m) rows.push_back(json::array({r[0], r[1], r[2]}));
    return rows;
}

/// Peak resident memory of this process so far (bytes). Ingest is the first stage of a run,
/// so right after it this bounds ingest's own peak.
int64_t peakRssBytes()
{
    rusage usage{};
    if (::getrusage(RUSAGE_SELF, &usage) != 0) return 0;
    return static_cast<int64_t>(usage.ru_maxrss) * 1024;  // Linux: kilobytes
}

} // namespace

json ingestToCtVdb(StageRun& run, const IngestParams& params, const ImageReadOptions& options,
                   const std::string& gridName, Progress* progress, openvdb::FloatGrid::Ptr& grid,
                   const std::function<void(const openvdb::FloatGrid::Ptr&)>& beforeWrite)
{
    IngestReport rep;
    {
        auto source = openImage(run.options.ctPath, options);
        for (const auto& w : source->warnings())
            if (run.options.log) run.options.log->message("ingest: warning: " + w);
        grid = ingestImage(*source, params, &rep, progress);
    }  // the source (and any temporary copy it made) is released before writing
    grid->setName(gridName);
    if (beforeWrite) beforeWrite(grid);
    // CT noise barely compresses (Blosc: -15% of the file for ~1 s of CPU on the critical path).
    writeGrids(run.path("ct.vdb"), {grid}, VdbValues::Raw);
    return json{{"world_frame", WORLD_FRAME},
                {"voxel_mm", rep.voxelMm},
                {"interpolation", rep.interpolation},
                {"active_voxels", rep.activeVoxels},
                {"memory_bytes", rep.memoryBytes},
                {"file_bytes", static_cast<int64_t>(fs::file_size(writtenFile(run.path("ct.vdb"))))},
                {"grid_size", rep.gridSize},
                {"grid_origin_mm", vec3Json(rep.gridOriginMm)},
                {"input_size", rep.inputSize},
                {"input_spacing_mm", vec3Json(rep.inputSpacingMm)},
                {"input_origin_mm", vec3Json(rep.inputOriginMm)},
                {"input_direction", matrixJson(rep.inputDirection)},
                {"reader", rep.source},
                {"reader_held_bytes", rep.sourceHeldBytes},
                {"working_bytes", rep.workingBytes},
                {"process_peak_rss_bytes", peakRssBytes()},
                {"warnings", rep.warnings}};
}

} // namespace flyover
