#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "pipeline/grid_write.h"
#include "pipeline/deferred_writes.h"
#include "colon/speculative_mesh.h"
#include "volume/image_io.h"
#include "volume/threads.h"
#include "volume/ingest.h"

#include <sys/resource.h>

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runIngest(StudyRun& run, Progress* progress)
{
    const IngestParams& params = run.opt.params.ingest;
    ImageReadOptions options;
    options.dicomSeriesUid = params.dicomSeries;
    options.allowGaps = params.allowGaps;
    openvdb::FloatGrid::Ptr grid;
    // Writing and hashing ct.vdb is one thread's work: the segmentation begins beside it (the
    // segment stage takes it, speculative_mesh.h), not with --threads 1.
    const bool threads = threadsThatMayRun() > 1;
    auto beginSegment = [&run](const openvdb::FloatGrid::Ptr& hu) {
        run.state.speculativeSegmentation = std::make_shared<SpeculativeSegmentation>(hu, run.opt.params.segment);
    };
    json report = ingestToCtVdb(run, params, options, "ct_hu", progress, grid,
                                threads && run.state.segmentWanted ? beginSegment
                                                                   : std::function<void(const openvdb::FloatGrid::Ptr&)>());
    run.state.hu = grid;
    return report;
}

} // namespace flyover
