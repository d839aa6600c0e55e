// The render steps, each a cached step of the stage graph with its own key (study.cpp lists
// the parameters each one depends on): fly-over frame pairs first, then fly-through pairs, the
// six OST overviews, the video (MP4 through the ffmpeg program) and coverage side by side.
//
// Artifacts (all folders are flat):
//   frames/                   pair_NNNN.png (camera 0 | camera 1), poses.json
//   flythrough/               pair_NNNN.png (forward | backward) at the same positions, poses.json
//   overview.png              the anterior overview (with the marker when one is asked for)
//   overviews/                <view>.png for the six canonical views, cameras.json
//   video/                    flyover.mp4, poses.json (schema flyover.video/1: every video frame's cameras)
//   coverage/                 coverage.json, surface_seen.ply
//   review/                   review_NNNN.png (review views for what the fly-over missed), poses.json
// The first fly-over pair is rendered and written before anything else, published in the
// study's frames/ at once and announced (report: first_pair_seconds).
#include "colon/study_run.h"

#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "pipeline/render_output.h"
#include "colon/anatomy_segments.h"
#include "colon/render_settings.h"
#include "colon/render_steps.h"
#include "render/camera.h"
#include "render/coverage.h"
#include "render/flyover_path.h"
#include "render/loop_ownership.h"
#include "render/overview.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "render/review.h"
#include "volume/error.h"
#include "volume/seconds_since.h"
#include "volume/object_pool.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_pipeline.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <functional>
#include <future>
#include <mutex>
#include <optional>
#include <sstream>
#include <condition_variable>
#include <thread>
#include <limits>
#include <memory>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

extern char** environ;

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

/// How a frame was rendered, so that any frame can be reproduced from the JSON alone.
json renderOptionsJson(const RenderOptions& ro)
{
    return json{{"width_px", ro.widthPx},       {"height_px", ro.heightPx},
                {"ost", ro.ost},                {"supersample", ro.supersample},
                {"smooth_shading", ro.smoothShading}, {"depth_cue", ro.depthCue},
                {"depth_cue_mm", ro.depthCueRangeMm}};
}

/// `ro` for a fly-over or review view standing at centerline index `index`: loop-local when
/// the run has owners (render.loop_reach_mm > 0).
RenderOptions loopLocal(RenderOptions ro, const RenderInputs& in, const RenderParams& rp, std::size_t index,
                        double clStep)
{
    if (in.ownerArcMm.empty()) return ro;
    ro.loop.ownerArcMm = &in.ownerArcMm;
    ro.loop.reachMm = rp.loopReachMm;
    ro.loop.arcMm = double(index) * clStep;
    return ro;
}

/// What loop-local OST did: the reach and how the owners were found (artifacts hold no
/// timings: the same inputs give the same files); `withSeconds` adds the time, for a report.
json loopJson(const RenderInputs& in, const RenderParams& rp, bool withSeconds)
{
    if (in.ownerArcMm.empty()) return json{{"enabled", false}};
    json j{{"enabled", true},
                {"reach_mm", rp.loopReachMm},
                {"owners_file", OWNERS_FILE},
                {"owners_by_sight", in.ownersBySight},
                {"owners_by_neighbour", in.ownersByNeighbour},
                {"unowned", in.unowned}};
    if (withSeconds) j["owners_seconds"] = in.ownersSeconds;
    return j;
}

namespace {

using Clock = std::chrono::steady_clock;

/// Centerline indices every `stepMm` of arc length from the first point.
std::vector<std::size_t> pathIndices(const Centerline& cl, double stepMm)
{
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    std::vector<std::size_t> indices;
    for (std::size_t k = 0;; ++k) {
        const auto i = static_cast<std::size_t>(std::llround(double(k) * stepMm / step));
        if (i >= cl.points.size()) break;
        if (indices.empty() || indices.back() != i) indices.push_back(i);
    }
    return indices;
}

std::string pairName(std::size_t frame)
{
    char name[32];
    std::snprintf(name, sizeof name, "pair_%04zu.png", frame);
    return name;
}



/// The fly-over cameras' settings and the frame images' options, as every step derives them.
struct FlyoverSetup {
    FlyoverParams fp;
    RenderOptions ro;
    double clStep;
};

FlyoverSetup flyoverSetup(const RenderParams& rp, const Centerline& cl)
{
    return FlyoverSetup{flyoverParamsOf(rp), frameOptionsOf(rp), cl.stepMm > 0 ? cl.stepMm : 1.0};
}

/// Makes DIR/frames a folder holding only the first pair (a hard link to the staged file), so
/// that a viewer finds it before the step ends; the commit then replaces the folder by the
/// complete one. Nothing records this folder: a run killed before the commit leaves a frames/
/// whose digest matches no record, which status reports and the next run replaces.
void publishFirstPair(const fs::path& dir, const std::string& stagedPair, const std::string& name)
{
    const std::string pid = std::to_string(::getpid());
    const fs::path tmp = dir / (".tmp-" + pid + "-first-frames"), old = dir / (".tmp-" + pid + "-old-first-frames");
    fs::remove_all(tmp);
    fs::remove_all(old);
    fs::create_directories(tmp);
    fs::create_hard_link(stagedPair, tmp / name);
    if (fs::exists(dir / "frames")) fs::rename(dir / "frames", old);
    fs::rename(tmp, dir / "frames");
    fs::remove_all(old);
}

/// Writes frames one at a time, in the order given, on a thread of its own (started by the
/// constructor, so it inherits the constructing thread's signal mask): write() waits for the
/// previous frame's write, hands the frame on and returns, so the caller must keep the frame
/// until its next write() or finish(). A failed write is rethrown by the next write() or finish().
class FrameWriter {
public:
    explicit FrameWriter(std::function<void(const RgbImage&)> sink)
        : mSink(std::move(sink)), mThread([this] { loop(); })
    {
    }
    ~FrameWriter() { stop(); }
    FrameWriter(const FrameWriter&) = delete;
    FrameWriter& operator=(const FrameWriter&) = delete;

    void write(const RgbImage& frame)
    {
        std::unique_lock<std::mutex> lock(mMutex);
        mIdle.wait(lock, [this] { return mPending == nullptr; });
        if (mError) std::rethrow_exception(mError);
        mPending = &frame;
        mWork.notify_one();
    }

    void finish()
    {
        stop();
        if (mError) std::rethrow_exception(mError);
    }

private:
    void loop()
    {
        std::unique_lock<std::mutex> lock(mMutex);
        for (;;) {
            mWork.wait(lock, [this] { return mPending != nullptr || mStop; });
            if (mPending == nullptr) return;  // stopped, nothing left
            const RgbImage* frame = mPending;
            lock.unlock();
            std::exception_ptr error;
            if (!mError) {
                try {
                    mSink(*frame);
                } catch (...) {
                    error = std::current_exception();
                }
            }
            lock.lock();
            if (error) mError = error;
            mPending = nullptr;
            mIdle.notify_all();
        }
    }

    void stop()
    {
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mStop = true;
            mWork.notify_one();
        }
        if (mThread.joinable()) mThread.join();
    }

    std::function<void(const RgbImage&)> mSink;
    std::mutex mMutex;
    std::condition_variable mWork, mIdle;
    const RgbImage* mPending = nullptr;
    bool mStop = false;
    std::exception_ptr mError;
    std::thread mThread;  // last: starts once the members above exist
};

} // namespace

RenderInputs::~RenderInputs() = default;

StudyRun::~StudyRun() = default;

namespace {

std::unique_ptr<SurfaceArrays> arraysOfMesh(const TriMesh& mesh)
{
    const auto t0 = Clock::now();
    auto arrays = std::make_unique<SurfaceArrays>();
    triMeshArrays(mesh, arrays->xyz, arrays->triangles);
    arrays->normals = smoothVertexNormals(arrays->xyz, arrays->triangles);
    arrays->prepareSeconds = secondsSince(t0);
    return arrays;
}

} // namespace

void StudyRun::prepareSurfaceArrays()
{
    const std::lock_guard<std::mutex> lock(mSurfaceMutex);
    if (mSurface || !state.mesh) return;
    mSurface = arraysOfMesh(*state.mesh);
    mSurface->preparedEarly = true;
}

SurfaceArrays& StudyRun::surfaceArrays()
{
    const std::lock_guard<std::mutex> lock(mSurfaceMutex);
    if (mSurface) return *mSurface;
    // From the mesh in memory, or from surface.ply's arrays (no topology).
    if (state.mesh) {
        mSurface = arraysOfMesh(*state.mesh);
    } else {
        const auto t0 = Clock::now();
        auto arrays = std::make_unique<SurfaceArrays>();
        if (!readPlainPly(path("surface.ply"), arrays->xyz, arrays->triangles)) {
            state.mesh = readMesh(path("surface.ply"));
            triMeshArrays(*state.mesh, arrays->xyz, arrays->triangles);
        }
        arrays->readSurfaceSeconds = secondsSince(t0);
        const auto t1 = Clock::now();
        arrays->normals = smoothVertexNormals(arrays->xyz, arrays->triangles);
        arrays->prepareSeconds = secondsSince(t1);
        mSurface = std::move(arrays);
    }
    return *mSurface;
}

const Centerline& StudyRun::renderCenterline()
{
    const std::lock_guard<std::mutex> lock(mSurfaceMutex);
    if (!state.centerline) {
        const auto t0 = Clock::now();
        state.centerline = centerlineFromJson(readJson(path("centerline.json")), path("centerline.json"));
        mReadCenterlineSeconds = secondsSince(t0);
    }
    if (state.centerline->points.empty()) throw InputError(path("centerline.json") + ": the centerline is empty");
    return *state.centerline;
}

const RenderInputs& StudyRun::renderInputs()
{
    tbb::collaborative_call_once(mRenderOnce, [this] {
        auto in = std::make_unique<RenderInputs>();
        SurfaceArrays& arrays = surfaceArrays();
        in->readSurfaceSeconds = arrays.readSurfaceSeconds;
        in->prepareSurfaceSeconds = arrays.prepareSeconds;
        in->surfacePreparedEarly = arrays.preparedEarly;
        const auto tScene = Clock::now();
        // The normals given are those the scene would compute (the same function): the same bits.
        in->scene = std::make_unique<RayScene>(std::move(arrays.xyz), std::move(arrays.triangles), arrays.normals);
        arrays = SurfaceArrays{};
        in->buildSceneSeconds = secondsSince(tScene);
        in->centerline = &renderCenterline();
        in->readCenterlineSeconds = mReadCenterlineSeconds;
        const auto tRadii = Clock::now();
        in->frameRadii = flyoverFrameRadii(*in->scene, *in->centerline, flyoverParamsOf(opt.params.render));
        in->frameRadiiSeconds = secondsSince(tRadii);
        const RenderParams& rp = opt.params.render;
        if (rp.ost && rp.loopReachMm > 0) {
            TriangleOwners owners = triangleOwners(*in->scene, *in->centerline);
            in->ownerArcMm = std::move(owners.arcMm);
            in->ownersBySight = owners.bySight;
            in->ownersByNeighbour = owners.byNeighbour;
            in->unowned = owners.unowned;
            in->ownersSeconds = owners.seconds;
        }
        mRender = std::move(in);
    });
    return *mRender;
}

namespace {

/// The first fly-over pair rendered from scenes of only the triangles it can meet (the full
/// scene of the other pairs is built after it): R(p) of its centerline point from a scene of
/// the triangles its fan rays (and those of its neighbours within reach) can hit, the same
/// double as flyoverFrameRadii gives; then its two cameras' frustum cull.
struct FirstPairFromSubset {
    std::array<Camera, 2> cameras;
    double frameRadiusMm = 0;
    std::size_t radiusTriangles = 0, pairTriangles = 0, surfaceTriangles = 0;
    double surfaceSeconds = 0, radiusSceneSeconds = 0, radiusSeconds = 0, pairSceneSeconds = 0;
};

FirstPairFromSubset firstPairScene(StudyRun& run, const FlyoverParams& fp, const RenderOptions& ro, std::size_t index,
                                   std::unique_ptr<RayScene>& pairScene)
{
    FirstPairFromSubset out;
    auto t = Clock::now();
    const SurfaceArrays& arrays = run.surfaceArrays();
    out.surfaceTriangles = arrays.triangles.size() / 3;
    out.surfaceSeconds = secondsSince(t);
    const Centerline& cl = run.renderCenterline();
    t = Clock::now();
    std::vector<uint32_t> radiusTris = frameRadiusTriangles(arrays.xyz, arrays.triangles, cl, fp, index);
    out.radiusTriangles = radiusTris.size() / 3;
    // Scenes for a few thousand rays: a fast (Morton) BVH build, the same hits (tested).
    SceneOptions fast;
    fast.fastBuild = true;
    const auto radiusScene = sceneOfTriangles(arrays.xyz, arrays.normals, radiusTris, fast);
    out.radiusSceneSeconds = secondsSince(t);
    t = Clock::now();
    out.frameRadiusMm = flyoverFrameRadiusAt(*radiusScene, cl, fp, index);
    out.radiusSeconds = secondsSince(t);
    t = Clock::now();
    out.cameras = flyoverCameras(cl.points[index], fp, out.frameRadiusMm);
    // Test hook (tests/pipeline): FLYOVER_TEST_FIRST_PAIR_CULL_MM moves the frustum's planes
    // (negative: inwards, dropping what the cameras see) to exercise the confirmation below.
    const char* testMargin = std::getenv("FLYOVER_TEST_FIRST_PAIR_CULL_MM");
    const std::vector<Camera> cameras{out.cameras[0], out.cameras[1]};
    std::vector<uint32_t> pairTris =
        testMargin ? frustumTriangles(arrays.xyz, arrays.triangles, cameras, ro.widthPx, ro.heightPx, std::atof(testMargin))
                   : frustumTriangles(arrays.xyz, arrays.triangles, cameras, ro.widthPx, ro.heightPx);
    out.pairTriangles = pairTris.size() / 3;
    pairScene = sceneOfTriangles(arrays.xyz, arrays.normals, pairTris, fast);
    out.pairSceneSeconds = secondsSince(t);
    return out;
}

/// Where the first pair's seconds went: the wait for the surface's arrays (prepared beside the
/// mesh stage's write), the frame radius's scene and the pair's cull and scene.
json firstPairBreakdown(const FirstPairFromSubset& first, const RenderInputs& in, double renderSeconds,
                        double pngSeconds)
{
    return json{{"wait_for_surface", first.surfaceSeconds},
                {"read_surface", in.readSurfaceSeconds},
                {"prepare_surface", in.prepareSurfaceSeconds},
                {"read_centerline", in.readCenterlineSeconds},
                {"frame_radius_scene", first.radiusSceneSeconds},
                {"frame_radius", first.radiusSeconds},
                {"pair_scene", first.pairSceneSeconds},
                {"render_pair", renderSeconds},
                {"write_png", pngSeconds}};
}

/// Which scene the first pair was rendered from, and how many triangles each kept.
json firstPairSceneJson(const FirstPairFromSubset& first)
{
    return json{{"scene", "frustum cull of the whole surface"},
                {"surface_triangles", first.surfaceTriangles},
                {"pair_triangles", first.pairTriangles},
                {"frame_radius_triangles", first.radiusTriangles},
                {"frame_radius_mm", first.frameRadiusMm}};
}

/// The frames report's loop-local part: the rule and, with owners, the share of wall pixels
/// passed through (all pairs together, the mean and the largest per pose).
json framesLoopReport(const RenderInputs& in, const RenderParams& rp, const std::vector<LoopCounts>& loopCounts)
{
    json report = loopJson(in, rp, true);
    if (in.ownerArcMm.empty()) return report;
    double sum = 0, worst = 0;
    LoopCounts all;
    for (const LoopCounts& c : loopCounts) {
        sum += c.passedShare();
        worst = std::max(worst, c.passedShare());
        all.wallPixels += c.wallPixels;
        all.passedPixels += c.passedPixels;
    }
    report["foreign_wall_share"] = all.passedShare();
    report["foreign_wall_share_mean_per_pose"] = sum / double(loopCounts.size());
    report["foreign_wall_share_max_per_pose"] = worst;
    return report;
}

} // namespace

json runFrames(StudyRun& run, Progress* progress)
{
    const auto tStart = Clock::now();
    const RenderParams& rp = run.opt.params.render;
    StagedFolder frames(run.dir, "frames");
    double firstRenderSeconds = 0, firstPngSeconds = 0;
    // Pair images reused from pair to pair (no allocation per pair), each lent to one pair at a
    // time: a thread waiting for a pair's tiles may take up another pair meanwhile (ObjectPool).
    ObjectPool<RgbImage> buffers([] { return RgbImage{}; });
    RgbImage firstShown;  // pair 0 as rendered from its own scenes, for the confirmation below
    auto renderFramePair = [&](const RayScene& scene, std::size_t f, const std::array<Camera, 2>& cams,
                               const RenderOptions& ro, LoopCounts* counts) {
        const auto t0 = Clock::now();
        const auto lease = buffers.take();
        RgbImage& pair = *lease;
        renderPair(scene, cams[0], cams[1], ro, pair, counts);
        const auto t1 = Clock::now();
        writePng(frames.path(pairName(f)), pair);
        if (f == 0) {
            firstRenderSeconds = std::chrono::duration<double>(t1 - t0).count();
            firstPngSeconds = secondsSince(t1);
            firstShown = pair;
        }
    };

    // The first pair before anything else, in the study's frames/ at once, announced: from
    // scenes of only the triangles its rays can meet (the same pixels: tested), the whole
    // scene after it. The frames step is the first render step to run, so nobody has taken
    // the surface's arrays into the whole scene yet.
    if (run.renderInputsBuilt()) throw std::logic_error("frames: the render scene was built before the first pair");
    const Centerline& firstCl = run.renderCenterline();
    const std::size_t index0 = pathIndices(firstCl, rp.frameStepMm).front();
    std::unique_ptr<RayScene> pairScene;
    const FirstPairFromSubset first = firstPairScene(run, flyoverParamsOf(rp), frameOptionsOf(rp), index0, pairScene);
    renderFramePair(*pairScene, 0, first.cameras, frameOptionsOf(rp), nullptr);
    pairScene.reset();
    const double firstPairSeconds = secondsSince(tStart);
    const double firstPairSinceRunStart = secondsSince(run.start);
    publishFirstPair(run.dir, frames.path(pairName(0)), pairName(0));
    if (run.opt.log) run.opt.log->firstPair(fs::absolute(run.path("frames/" + pairName(0))).string());
    crashPoint("frames:first-pair");

    // The whole scene, before the write-behind's commits (the fsyncs, the mesh checks) start:
    // the BVH build's temporaries and theirs would add up.
    const auto tInputs = Clock::now();
    const RenderInputs& in = run.renderInputs();
    const double inputsSeconds = secondsSince(tInputs);
    run.handOn("frames:first-pair");
    const RayScene& scene = *in.scene;
    const Centerline& cl = *in.centerline;
    const FlyoverSetup s = flyoverSetup(rp, cl);
    const std::vector<std::size_t> indices = pathIndices(cl, rp.frameStepMm);
    // The first pair shown came from scenes of a cull (the same pixels in every test): it is
    // confirmed on the whole scene (one pair, ~0.01 s) and, should it differ, replaced, so that
    // frames/ is always the whole scene's rendering; the log and the report say so.
    // With loop-local OST the whole scene's pair also passes through other loops' walls, which
    // the first pair's cull (rendered before the owners exist) shows.
    json firstConfirmed;
    std::vector<LoopCounts> loopCounts(indices.size());
    {
        const auto cams = flyoverCameras(cl.points[indices[0]], s.fp, in.frameRadii[indices[0]]);
        const auto lease = buffers.take();
        RgbImage& whole = *lease;
        renderPair(scene, cams[0], cams[1], loopLocal(frameOptionsOf(rp), in, rp, indices[0], s.clStep), whole,
                   &loopCounts[0]);
        const std::size_t differing = differingPixels(firstShown, whole);
        const bool sameRadius = first.frameRadiusMm == in.frameRadii[indices[0]];
        firstConfirmed = json{{"confirmed_on_whole_scene", true},
                              {"same_frame_radius", sameRadius},
                              {"differing_pixels", differing},
                              {"replaced", differing > 0}};
        if (differing > 0) {
            writePng(frames.path(pairName(0)), whole);
            if (run.opt.log) {
                std::ostringstream msg;
                msg << "frames: the first pair shown (from its scene of " << first.pairTriangles << " of "
                    << first.surfaceTriangles << " triangles" << (in.ownerArcMm.empty() ? "" : ", every wall shown")
                    << ") differed from the whole scene's" << (in.ownerArcMm.empty() ? "" : " loop-local pair")
                    << " in " << differing << " pixels" << (sameRadius ? "" : " (frame radius differed)")
                    << "; frames/" << pairName(0) << " is now the whole scene's";
                run.opt.log->message(msg.str());
            }
        }
    }
    std::vector<json> poses(indices.size());
    auto poseOf = [&](std::size_t f, const std::array<Camera, 2>& cams) {
        const CenterlinePoint& p = cl.points[indices[f]];
        poses[f] = json{{"frame", f},
                        {"file", pairName(f)},
                        {"centerline_index", indices[f]},
                        {"arc_mm", double(indices[f]) * s.clStep},
                        {"centerline_point_mm", vec3Json(p.positionMm)},
                        {"radius_mm", p.radiusMm},
                        {"frame_radius_mm", in.frameRadii[indices[f]]},
                        {"cameras", json::array({cameraJson(cams[0]), cameraJson(cams[1])})}};
        if (!in.ownerArcMm.empty()) poses[f]["foreign_wall_share"] = loopCounts[f].passedShare();
    };
    poseOf(0, flyoverCameras(cl.points[indices[0]], s.fp, in.frameRadii[indices[0]]));

    const auto tRest = Clock::now();
    std::atomic<std::size_t> done{1};
    tbb::parallel_for(std::size_t(1), indices.size(), [&](std::size_t f) {
        const auto cams = flyoverCameras(cl.points[indices[f]], s.fp, in.frameRadii[indices[f]]);
        renderFramePair(scene, f, cams, loopLocal(frameOptionsOf(rp), in, rp, indices[f], s.clStep), &loopCounts[f]);
        poseOf(f, cams);
        reportProgress(progress, double(++done) / double(indices.size()), "fly-over frame pairs");
    });
    if (!in.ownerArcMm.empty()) writeOwners(frames.path(OWNERS_FILE), in.ownerArcMm);
    writeJson(frames.path("poses.json"),
              json{{"schema", "flyover.poses/1"},
                   {"world_frame", WORLD_FRAME},
                   {"image_size_px", {rp.widthPx, rp.heightPx}},
                   {"layout", "pair images: camera 0 left, camera 1 right"},
                   {"ost", rp.ost},
                   {"render", renderOptionsJson(s.ro)},
                   {"loop_local", loopJson(in, rp)},
                   {"frames", poses}});
    frames.commit();
    const json loopReport = framesLoopReport(in, rp, loopCounts);
    RenderedPairs shared;
    for (std::size_t f = 0; f < indices.size(); ++f) {
        shared.centerlineIndices.push_back(indices[f]);
        shared.files.push_back(run.path("frames/" + pairName(f)));
    }
    run.state.framePairs = std::move(shared);
    return json{{"frame_pairs", indices.size()},
                {"triangles", scene.triangleCount()},
                {"first_pair_seconds", firstPairSeconds},
                {"first_pair_seconds_since_run_start", firstPairSinceRunStart},
                {"first_pair_breakdown_seconds", firstPairBreakdown(first, in, firstRenderSeconds, firstPngSeconds)},
                {"first_pair_scene", firstPairSceneJson(first)},
                {"first_pair_check", firstConfirmed},
                {"loop_local", loopReport},
                {"surface_prepared_early", in.surfacePreparedEarly},
                {"whole_scene_seconds",
                 {{"wait_for_inputs", inputsSeconds},
                  {"build_scene", in.buildSceneSeconds},
                  {"frame_radii", in.frameRadiiSeconds}}},
                {"other_pairs_seconds", secondsSince(tRest)}};
}

json runFlythrough(StudyRun& run, Progress* progress)
{
    const RenderParams& rp = run.opt.params.render;
    StagedFolder flythrough(run.dir, "flythrough");
    std::size_t pairs = 0;
    if (rp.flythroughFrames) {
        const RenderInputs& in = run.renderInputs();
        const Centerline& cl = *in.centerline;
        const FlyoverSetup s = flyoverSetup(rp, cl);
        const std::vector<std::size_t> indices = pathIndices(cl, rp.frameStepMm);
        std::vector<json> ftPoses(indices.size());
        std::atomic<std::size_t> done{0};
        ObjectPool<RgbImage> buffers([] { return RgbImage{}; });  // as in runFrames
        tbb::parallel_for(std::size_t(0), indices.size(), [&](std::size_t f) {
            const CenterlinePoint& p = cl.points[indices[f]];
            const Camera fwd = flythroughCamera(p, true, rp.flythroughFovDeg);
            const Camera back = flythroughCamera(p, false, rp.flythroughFovDeg);
            const auto lease = buffers.take();
            renderPair(*in.scene, fwd, back, s.ro, *lease);
            writePng(flythrough.path(pairName(f)), *lease);
            ftPoses[f] = json{{"frame", f},
                              {"file", pairName(f)},
                              {"centerline_index", indices[f]},
                              {"arc_mm", double(indices[f]) * s.clStep},
                              {"cameras", json::array({cameraJson(fwd), cameraJson(back)})}};
            reportProgress(progress, double(++done) / double(indices.size()), "fly-through frame pairs");
        });
        writeJson(flythrough.path("poses.json"),
                  json{{"schema", "flyover.poses/1"},
                       {"world_frame", WORLD_FRAME},
                       {"layout", "pair images: forward (rectum -> cecum) left, backward right"},
                       {"render", renderOptionsJson(s.ro)},
                       {"frames", ftPoses}});
        pairs = indices.size();
    }
    flythrough.commit();
    return json{{"frame_pairs", pairs}};
}

json runOverviews(StudyRun& run, Progress* progress)
{
    const RenderParams& rp = run.opt.params.render;
    const RenderInputs& in = run.renderInputs();
    const RayScene& scene = *in.scene;
    const Centerline& cl = *in.centerline;
    const double clStep = cl.stepMm > 0 ? cl.stepMm : 1.0;
    StagedFolder overviews(run.dir, "overviews");
    RenderOptions ov;
    ov.widthPx = ov.heightPx = rp.overviewPx;
    ov.ost = rp.ost;
    ov.supersample = std::max(rp.supersample, 2);
    ov.smoothShading = rp.smoothShading;
    ov.depthCue = rp.depthCue;  // range 0: half the scene's diagonal
    std::optional<OverviewMarker> marker;
    if (rp.overviewMarkerMm >= 0) {
        const auto i = std::min(cl.points.size() - 1, std::size_t(std::llround(rp.overviewMarkerMm / clStep)));
        marker = OverviewMarker{cl.points[i].positionMm, std::max(cl.points[i].radiusMm, 1.0)};
    }
    json overviewCameras = json::object();
    RgbImage anterior;
    std::size_t done = 0;
    for (const CanonicalView& view : canonicalViews()) {
        const Camera cam = overviewCamera(scene.boundsMin(), scene.boundsMax(), view.viewDir, view.up, 30.0);
        RgbImage image = renderView(scene, cam, ov);
        if (marker) drawMarker(image, cam, *marker);
        writePng(overviews.path(std::string(view.name) + ".png"), image);
        overviewCameras[view.name] = cameraJson(cam);
        if (std::string(view.name) == "anterior") anterior = std::move(image);
        reportProgress(progress, double(++done) / double(canonicalViews().size()), "overviews");
    }
    json overviewInfo{{"schema", "flyover.overviews/1"},
                      {"world_frame", WORLD_FRAME},
                      {"render", renderOptionsJson(ov)},
                      {"cameras", overviewCameras}};
    if (marker)
        overviewInfo["marker"] = json{{"arc_mm", rp.overviewMarkerMm},
                                      {"position_mm", vec3Json(marker->positionMm)},
                                      {"radius_mm", marker->radiusMm}};
    writeJson(overviews.path("cameras.json"), overviewInfo);
    writePng(run.path("overview.png"), anterior);
    overviews.commit();
    return json{{"overview_camera", overviewCameras["anterior"]}};
}

json runVideo(StudyRun& run, Progress* progress)
{
    const RenderParams& rp = run.opt.params.render;
    StagedFolder videoDir(run.dir, "video");
    std::size_t frameCount = 0, reusedPairs = 0;
    if (rp.video) {
        const std::string ffmpeg = findOnPath("ffmpeg");
        if (ffmpeg.empty())
            throw std::runtime_error("render.video: the 'ffmpeg' program is not on PATH; install it "
                                     "(Debian: apt-get install ffmpeg) or set render.video=false");
        const RenderInputs& in = run.renderInputs();
        const Centerline& cl = *in.centerline;
        const FlyoverSetup s = flyoverSetup(rp, cl);
        const std::vector<std::size_t> vIdx = pathIndices(cl, rp.videoStepMm);
        const int pairWidth = 2 * rp.widthPx + PAIR_GAP_PX;
        std::vector<json> vPoses;
        // The frames step of this run rendered the pairs at its centerline indices with the
        // same cameras and options (both from this run's parameters): those frames are read
        // back (PNG is lossless) instead of rendered again.
        const RenderedPairs* framePairs = run.state.framePairs ? &*run.state.framePairs : nullptr;
        auto framePairFile = [&](std::size_t centerlineIndex) -> const std::string* {
            if (!framePairs) return nullptr;
            const auto& ids = framePairs->centerlineIndices;
            const auto it = std::lower_bound(ids.begin(), ids.end(), centerlineIndex);
            if (it == ids.end() || *it != centerlineIndex) return nullptr;
            return &framePairs->files[std::size_t(it - ids.begin())];
        };
        // The frames are rendered (or read back) several at a time by whichever threads are
        // free, so that the video, the longest render step, keeps both cores busy once the
        // other steps have ended; they reach ffmpeg in order (the MP4 is the same, byte for
        // byte). The writer is a thread of this step's own: FfmpegVideo blocks SIGPIPE on the
        // thread that made it, and a thread it starts inherits that.
        constexpr std::size_t IN_FLIGHT = 4;  // frames rendered at once, at most
        const std::size_t n = vIdx.size();
        std::vector<json> cameraPoses(n);
        std::atomic<std::size_t> reused{0};
        writeAtomically(videoDir.path("flyover.mp4"), [&](const std::string& tmp) {
            FfmpegVideo video(ffmpeg, tmp, videoDir.path(".ffmpeg.log"), pairWidth, rp.heightPx, rp.videoFps);
            // Frames in flight are consecutive (the last filter takes them in order), plus the
            // one being written: slot k % (IN_FLIGHT + 1) is free when frame k enters.
            std::vector<RgbImage> slots(IN_FLIGHT + 1);
            FrameWriter writer([&video](const RgbImage& frame) { video.write(frame); });
            std::size_t next = 0;
            tbb::parallel_pipeline(
                IN_FLIGHT,
                tbb::make_filter<void, std::size_t>(tbb::filter_mode::serial_in_order,
                                                    [&](tbb::flow_control& fc) -> std::size_t {
                                                        if (next == n) fc.stop();
                                                        return next < n ? next++ : 0;
                                                    }) &
                    tbb::make_filter<std::size_t, std::size_t>(
                        tbb::filter_mode::parallel,
                        [&](std::size_t k) {
                            const auto cams = flyoverCameras(cl.points[vIdx[k]], s.fp, in.frameRadii[vIdx[k]]);
                            RgbImage& pair = slots[k % slots.size()];
                            if (const std::string* file = framePairFile(vIdx[k])) {
                                pair = readPng(*file);
                                if (pair.width != pairWidth || pair.height != rp.heightPx)
                                    throw std::runtime_error(
                                        *file + ": a fly-over pair of " + std::to_string(pair.width) + " x " +
                                        std::to_string(pair.height) + " px where the video needs " +
                                        std::to_string(pairWidth) + " x " + std::to_string(rp.heightPx));
                                ++reused;
                            } else {
                                renderPair(*in.scene, cams[0], cams[1], loopLocal(s.ro, in, rp, vIdx[k], s.clStep),
                                           pair);
                            }
                            cameraPoses[k] = json{{"frame", k},
                                                  {"centerline_index", vIdx[k]},
                                                  {"arc_mm", double(vIdx[k]) * s.clStep},
                                                  {"cameras", json::array({cameraJson(cams[0]), cameraJson(cams[1])})}};
                            return k;
                        }) &
                    tbb::make_filter<std::size_t, void>(tbb::filter_mode::serial_in_order, [&](std::size_t k) {
                        writer.write(slots[k % slots.size()]);  // waits for frame k - 1's write
                        if (k % 32 == 0) reportProgress(progress, double(k + 1) / double(n), "video frames");
                    }));
            writer.finish();  // rethrows a failed write
            video.finish();
        });
        vPoses = std::move(cameraPoses);
        fs::remove(videoDir.path(".ffmpeg.log"));
        writeJson(videoDir.path("poses.json"),
                  json{{"schema", "flyover.video/1"},
                       {"world_frame", WORLD_FRAME},
                       {"file", "flyover.mp4"},
                       {"codec", "H.264 (libx264 ultrafast, yuv420p, crf 20)"},
                       {"fps", rp.videoFps},
                       {"step_mm", rp.videoStepMm},
                       {"image_size_px", {pairWidth, rp.heightPx}},
                       {"layout", "pair images: camera 0 left, camera 1 right"},
                       {"render", renderOptionsJson(s.ro)},
                       {"loop_local", loopJson(in, rp)},
                       {"frames", vPoses}});
        frameCount = vIdx.size();
        reusedPairs = reused.load();
    }
    videoDir.commit();
    return json{{"video_frames", frameCount}, {"frames_from_frame_pairs", reusedPairs}};
}


} // namespace flyover
