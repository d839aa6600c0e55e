// Inspect's stage table and its entry points on the engine.
#include "inspect/inspect_study.h"

#include "inspect/part_surface.h"
#include "inspect/voids.h"
#include "volume/error.h"

namespace flyover {

namespace {

using nlohmann::json;

template <json (*Body)(PartRun&, Progress*)>
json partBody(StageRun& run, Progress* progress)
{
    return Body(static_cast<PartRun&>(run), progress);
}

StudyPipeline makeInspectPipeline()
{
    const char* const render = "render";
    StudyPipeline p;
    p.name = "inspect";
    p.manifestName = "inspect";
    p.stagePrefix = "inspect:";
    p.studyWord = "part (flyover inspect)";
    p.stages = {
        {"ingest", {}, {"input"}, {"ct.vdb"}, partBody<runPartIngest>, "", {}, {}, true},
        {"voids", {"ingest"}, {"ct.vdb"}, {"voids.csv", "voids.json", "voids.vdb"}, partBody<runVoids>},
        {"surfaces", {"voids"}, {"ct.vdb", "voids.vdb", "voids.json"}, {"part_surface.ply", "surfaces.json"},
         partBody<runPartSurfaces>},
        {"overviews", {"surfaces"}, {"part_surface.ply", "surfaces.json", "voids.json"}, {"overview.png", "overviews"},
         partBody<runPartOverviews>, render, {"overview_px", "supersample", "smooth_shading", "depth_cue"}},
        {"turntable", {"surfaces"}, {"part_surface.ply", "surfaces.json", "voids.json"}, {"turntable"},
         partBody<runTurntable>, render,
         {"video", "turntable_frames", "video_fps", "video_px", "supersample", "smooth_shading", "depth_cue"},
         {"overviews"}},
    };
    for (const auto& s : p.stages) p.commandStages.push_back(s.name);
    p.firstStageHint = "the first stage ('flyover stage inspect:ingest --ct CT') creates it";
    p.defaultParams = [] { return std::make_unique<InspectParamSet>(); };
    p.run = [](const StudyOptions& o, const ParamSet& params) {
        InspectRunOptions run;
        static_cast<StudyOptions&>(run) = o;
        run.params = dynamic_cast<const InspectParamSet&>(params).params;
        return runInspect(run);
    };
    return p;
}

} // namespace

const StudyPipeline& inspectPipeline()
{
    static const StudyPipeline pipeline = makeInspectPipeline();
    static const bool registered = (registerStudyPipeline(pipeline), true);
    (void)registered;
    return pipeline;
}

json runInspect(const InspectRunOptions& options)
{
    validateInspectParams(options.params);
    if (!options.maskPath.empty()) throw ParameterError("inspect: takes no --mask");
    PartRun run(options);
    return runStudy(inspectPipeline(), run);
}

} // namespace flyover
