// The colon's stage table and its entry points on the engine.
#include "colon/colon_study.h"

#include "colon/study_run.h"
#include "pipeline/artifact_io.h"

namespace flyover {

openvdb::FloatGrid::Ptr StudyRun::sdf()
{
    std::lock_guard<std::mutex> lock(mLoadMutex);
    if (!state.sdf)
        state.sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(path("lumen.vdb"), "lumen_sdf"));
    return state.sdf;
}

namespace {

using nlohmann::json;

/// A stage body of the colon's table, on the colon's run context.
template <json (*Body)(StudyRun&, Progress*)>
json colonBody(StageRun& run, Progress* progress)
{
    return Body(static_cast<StudyRun&>(run), progress);
}

template <void (*Body)(StudyRun&, Progress*)>
void colonEarly(StageRun& run, Progress* progress)
{
    Body(static_cast<StudyRun&>(run), progress);
}

/// The segment stage: from the CT's air, or from the external mask when the run has one.
json runSegmentStage(StudyRun& run, Progress* progress)
{
    return run.opt.maskPath.empty() ? runSegment(run, progress) : runSegmentFromMask(run, run.opt.maskPath, progress);
}

// The render parameters each render step depends on.
#define FLYOVER_CAMERA "fov_deg", "roll_deg", "direction", "clip_offset_fraction", "clip_offset_mm", "loop_reach_mm"
#define FLYOVER_IMAGE "width_px", "height_px", "supersample", "ost", "smooth_shading", "depth_cue", "depth_cue_mm"

std::vector<StageSpec> colonStages()
{
    const char* const render = "render";
    const std::vector<std::string> renderIn{"surface.ply", "centerline.json"};
    const std::vector<std::string> renderUp{"centerline", "mesh"};
    // The video, the longest render step and the one that runs mostly on one thread, starts
    // first (priority 2) so that it does not run alone at the end of the run.
    return {
        {"ingest", {}, {"input"}, {"ct.vdb"}, colonBody<runIngest>, "", {}, {}, true},
        {"segment", {"ingest"}, {"ct.vdb"}, {"lumen.vdb"}, colonBody<runSegmentStage>, "", {}, {}, true, true},
        {"centerline", {"segment"}, {"lumen.vdb"}, {"centerline.json"}, colonBody<runCenterline>, "", {}, {}, true},
        {"mesh", {"segment"}, {"lumen.vdb"}, {"surface.ply"}, colonBody<runMesh>, "", {}, {}, true},
        {"frames", renderUp, renderIn, {"frames"}, colonBody<runFrames>, render,
         {FLYOVER_CAMERA, FLYOVER_IMAGE, "frame_step_mm"}},
        {"flythrough", renderUp, renderIn, {"flythrough"}, colonBody<runFlythrough>, render,
         {"flythrough_frames", "flythrough_fov_deg", "frame_step_mm", FLYOVER_IMAGE}, {"frames"}},
        {"overviews", renderUp, renderIn, {"overview.png", "overviews"}, colonBody<runOverviews>, render,
         {"overview_px", "overview_marker_mm", "ost", "supersample", "smooth_shading", "depth_cue"}, {"frames"}},
        {"video", renderUp, renderIn, {"video"}, colonBody<runVideo>, render,
         {"video", "video_step_mm", "video_fps", FLYOVER_CAMERA, FLYOVER_IMAGE}, {"frames"}, false, false, 2},
        {"coverage", renderUp, renderIn, {"coverage", "review"}, colonBody<runCoverage>, render,
         {"coverage", "review", "review_target", "coverage_px", "coverage_step_mm", "flythrough_fov_deg", FLYOVER_CAMERA,
          FLYOVER_IMAGE},
         {"frames"}, false, false, 1},
        // Polyp candidates: from the level set and the path; their pairs from the render
        // steps' scene (after the frames, which build it), keyed by the render parameters
        // those pairs take.
        {"polyps", {"centerline", "mesh"}, {"lumen.vdb", "surface.ply", "centerline.json"}, {"polyps"},
         colonBody<runPolyps>, "polyps", {}, {"frames"}, false, false, 0, {"ct.vdb"},
         {"render.fov_deg", "render.direction", "render.clip_offset_fraction", "render.clip_offset_mm", "render.loop_reach_mm", "render.width_px", "render.height_px", "render.supersample", "render.ost", "render.smooth_shading", "render.depth_cue", "render.depth_cue_mm"}},
    };
}

#undef FLYOVER_CAMERA
#undef FLYOVER_IMAGE

std::vector<EarlySpec> colonEarlyWork()
{
    // Writing and hashing ct.vdb, and the contact cut, run mostly on one thread; the surface's
    // render arrays are prepared while surface.ply is written and hashed.
    return {
        {"segmentation beside ct.vdb's write", "ingest:hu", {"segment"}, colonEarly<segmentEarly>},
        {"mesh of the uncut lumen", "segment:uncut-lumen", {"mesh"}, colonEarly<meshUncutLumen>},
        {"centerline of the uncut lumen", "segment:uncut-lumen", {"centerline"}, colonEarly<traceUncutLumen>},
        {"render arrays of the surface", "mesh:mesh", {"frames", "flythrough", "overviews", "video", "coverage"},
         colonEarly<prepareSurfaceEarly>},
    };
}

StudyPipeline makeColonPipeline()
{
    StudyPipeline p;
    p.name = "colon";
    p.manifestName = "";
    p.stagePrefix = "";
    p.studyWord = "colon (flyover run)";
    p.stages = colonStages();
    p.early = colonEarlyWork();
    // The write-behind's commits wait for the first pair out and the whole scene built after it.
    p.commitsAfter = "frames:first-pair";
    p.commandStages = stageNames();
    p.firstStageHint = "the first stage ('flyover stage ingest --ct CT' or 'flyover stage segment --mask FILE') creates it";
    p.defaultParams = [] { return std::make_unique<ColonParamSet>(); };
    p.run = [](const StudyOptions& o, const ParamSet& params) {
        RunOptions run;
        static_cast<StudyOptions&>(run) = o;
        run.params = dynamic_cast<const ColonParamSet&>(params).params;
        return runPipeline(run);
    };
    return p;
}

} // namespace

const StudyPipeline& colonPipeline()
{
    static const StudyPipeline pipeline = [] {
        StudyPipeline p = makeColonPipeline();
        return p;
    }();
    static const bool registered = (registerStudyPipeline(pipeline), true);
    (void)registered;
    return pipeline;
}

json runPipeline(const RunOptions& options)
{
    StudyRun run(options);
    return runStudy(colonPipeline(), run);
}

std::vector<StageStatus> studyStatus(const StatusOptions& options)
{
    colonPipeline();
    StudyStatusOptions so;
    so.studyDir = options.studyDir;
    so.ctPath = options.ctPath;
    so.maskPath = options.maskPath;
    const ColonParamSet given(options.params);
    if (options.paramsGiven) so.params = &given;
    return studyStatus(so);
}

std::vector<std::string> stagesNeededFor(const std::string& stage) { return stagesNeededFor(colonPipeline(), stage); }
std::vector<std::string> stagesAffectedBy(const std::string& stage) { return stagesAffectedBy(colonPipeline(), stage); }

} // namespace flyover
