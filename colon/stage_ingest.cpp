#include "colon/study_run.h"

#include "pipeline/artifact_io.h"
#include "pipeline/grid_write.h"
#include "pipeline/deferred_writes.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

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
    // Writing and hashing ct.vdb is one thread's work: the HU grid is handed on before it, for
    // the segmentation made beside it (the early node "segmentation beside ct.vdb's write").
    auto handOn = [&run](const openvdb::FloatGrid::Ptr& hu) {
        run.state.hu = hu;
        run.handOn("ingest:hu");
    };
    json report = ingestToCtVdb(run, params, options, "ct_hu", progress, grid,
                                run.earlyReaders("ingest:hu") > 0 ? handOn
                                                                  : std::function<void(const openvdb::FloatGrid::Ptr&)>());
    if (!run.state.hu) run.state.hu = grid;  // handed on already: the early node may be reading it
    return report;
}

} // namespace flyover
