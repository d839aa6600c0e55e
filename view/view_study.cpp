#include "view/view_study.h"
#include "volume/vec3.h"

#include "pipeline/artifact_io.h"
#include "colon/render_settings.h"
#include "render/flyover_path.h"
#include "render/loop_ownership.h"
#include "render/overview.h"
#include "volume/error.h"
#include "volume/image.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <set>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

json vec3(const Vec3d& v) { return json::array({v.x, v.y, v.z}); }

json cameraJson(const Camera& c)
{
    return json{{"position_mm", vec3(c.position)}, {"forward", vec3(c.forward)}, {"up", vec3(c.up)},
                {"right", vec3(c.right)},         {"fov_deg", c.fovDeg},       {"near_mm", c.nearMm}};
}

/// The render stage's parameters of the last run (manifest.json), else the defaults.
RenderParams renderParamsOf(const fs::path& dir)
{
    PipelineParams params;
    const fs::path manifest = dir / "manifest.json";
    if (!fs::exists(manifest)) return params.render;
    const json m = readJson(manifest.string());
    if (m.contains("stages") && m["stages"].is_array())
        for (const auto& e : m["stages"])
            // "render" in studies made before the render steps; each step records the render
            // parameters it uses (frames: cameras and image; coverage; ...): together they are all.
            if (e.is_object() && e.contains("parameters") &&
                std::set<std::string>{"render", "frames", "flythrough", "overviews", "video", "coverage"}.count(
                    e.value("stage", "")))
                applyParamsJson(params, json{{"render", e["parameters"]}}, manifest.string());
    return params.render;
}

/// `flyover run ...` as it would remake this study (the recorded input when there is one).
std::string runHintOf(const fs::path& dir)
{
    std::string input = "CT", mask;
    const fs::path manifest = dir / "manifest.json";
    try {
        if (fs::exists(manifest)) {
            const json m = readJson(manifest.string());
            auto pathOf = [&](const char* key) -> std::string {
                return m.contains(key) && m[key].is_string() ? m[key].get<std::string>() : "";
            };
            const std::string ct = pathOf("input"), mk = pathOf("mask");
            if (!ct.empty()) input = ct;
            if (!mk.empty()) mask = " --mask " + mk, input = ct.empty() ? "" : ct;
        }
    } catch (const std::exception&) {
        // a broken manifest: the generic command
    }
    std::string cmd = "flyover run";
    if (!input.empty()) cmd += " " + input;
    return cmd + mask + " --study " + dir.string();
}

} // namespace

ViewStudy::ViewStudy(const std::string& studyDir, const std::string& ctPath) : mDir(studyDir)
{
    const fs::path dir(studyDir);
    if (!fs::is_directory(dir)) throw InputError("view: " + studyDir + ": no such study folder");
    mRunHint = runHintOf(dir);
    for (const char* need : {"centerline.json", "surface.ply"})
        if (!fs::is_regular_file(dir / need))
            throw InputError("view: " + studyDir + " lacks " + need + " (" +
                             (std::string(need) == "surface.ply" ? "the mesh stage" : "the centerline stage") +
                             "); make it with: " + mRunHint);
    const std::string clPath = (dir / "centerline.json").string();
    mCenterline = centerlineFromJson(readJson(clPath), clPath);
    if (mCenterline.points.size() < 2) throw InputError("view: " + clPath + ": the centerline has fewer than 2 points");
    if (!(mCenterline.stepMm > 0)) mCenterline.stepMm = 1.0;
    mParams = renderParamsOf(dir);
    const fs::path cov = dir / "coverage" / "coverage.json";
    if (fs::is_regular_file(cov)) mCoverage = readJson(cov.string());
    if (!ctPath.empty()) {
        if (!fs::exists(ctPath)) throw InputError("view: --ct " + ctPath + ": no such file or folder");
        mCtSource = ctPath;
    } else if (fs::is_regular_file(dir / "ct.vdb")) {
        mCtSource = (dir / "ct.vdb").string();
    }
}

ViewStudy::~ViewStudy()
{
    if (mLoader.joinable()) mLoader.join();
}

void ViewStudy::loadNow()
{
    std::string error;
    try {
        const std::string ply = (fs::path(mDir) / "surface.ply").string();
        std::shared_ptr<const RayScene> scene = mReusedScene;
        if (!scene) {
            std::vector<float> xyz;
            std::vector<uint32_t> tris;
            // Only the layout flyover writes: OpenMesh's general reader can allocate without bound
            // on a malformed header (measured: gigabytes for a 3-line file), so it is never tried here.
            if (!readPlainPly(ply, xyz, tris))
                throw InputError(ply + ": not the binary PLY layout flyover writes (float x y z, triangles); remake it "
                                       "with: " + mRunHint + " --force mesh");
            SceneOptions options;
            options.fastBuild = mFastScene;
            scene = std::make_shared<const RayScene>(std::move(xyz), std::move(tris), options);
        }
        mReusedScene.reset();
        if (scene->triangleCount() == 0) throw InputError(ply + ": the surface has no triangles");
        openvdb::FloatGrid::Ptr ct;
        if (mReusedCt) {  // its bounds and spacing were copied by reuse()
            ct = std::move(mReusedCt);
        } else if (!mCtSource.empty()) {
            if (fs::path(mCtSource).extension() == ".vdb") {
                ct = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(mCtSource, "ct_hu"));
                if (!ct) throw InputError(mCtSource + ": grid ct_hu is not a float grid");
            } else {
                auto source = openImage(mCtSource, ImageReadOptions{});
                ct = ingestImage(*source, IngestParams{});
            }
            const openvdb::CoordBBox box = ct->evalActiveVoxelBoundingBox();
            if (box.empty()) throw InputError(mCtSource + ": the CT grid has no active voxels");
            Vec3d lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
            for (int k = 0; k < 8; ++k) {
                const openvdb::Vec3d c((k & 1) ? box.max().x() : box.min().x(), (k & 2) ? box.max().y() : box.min().y(),
                                       (k & 4) ? box.max().z() : box.min().z());
                const openvdb::Vec3d w = ct->indexToWorld(c);
                lo = Vec3d{std::min(lo.x, w.x()), std::min(lo.y, w.y()), std::min(lo.z, w.z())};
                hi = Vec3d{std::max(hi.x, w.x()), std::max(hi.y, w.y()), std::max(hi.z, w.z())};
            }
            const openvdb::Vec3d vs = ct->voxelSize();
            std::lock_guard<std::mutex> lock(mLoadMutex);
            mCtMin = lo;
            mCtMax = hi;
            mCtSpacing = {vs.x(), vs.y(), vs.z()};
        }
        // The frames step's owners when they are this surface's, else computed as it does.
        std::vector<float> owners;
        if (mParams.ost && mParams.loopReachMm > 0 && !mCenterline.points.empty() &&
            !readOwners((fs::path(mDir) / "frames" / OWNERS_FILE).string(), scene->triangleCount(), owners))
            owners = triangleOwners(*scene, mCenterline).arcMm;
        std::lock_guard<std::mutex> lock(mLoadMutex);
        mScene = std::move(scene);
        mOwners = std::move(owners);
        mCt = ct;
    } catch (const std::exception& e) {
        error = e.what();
        if (error.empty()) error = "view: loading the study failed";
    }
    {
        std::lock_guard<std::mutex> lock(mLoadMutex);
        mLoadError = error;
        mLoaded = true;
    }
    mLoadedCv.notify_all();
}

void ViewStudy::reuse(const ViewStudy& previous, bool surface, bool ct)
{
    previous.waitLoaded();
    if (surface) mReusedScene = previous.mScene;
    if (ct && previous.mCt && previous.mCtSource == mCtSource) {
        std::lock_guard<std::mutex> lock(mLoadMutex);
        mReusedCt = previous.mCt;
        mCtMin = previous.mCtMin;
        mCtMax = previous.mCtMax;
        mCtSpacing = previous.mCtSpacing;
    }
}

void ViewStudy::startLoading()
{
    if (mLoader.joinable()) return;
    mLoader = std::thread([this] { loadNow(); });
}

void ViewStudy::load()
{
    if (mLoader.joinable()) {
        waitLoaded();
        return;
    }
    loadNow();
    waitLoaded();
}

void ViewStudy::waitLoaded() const
{
    std::unique_lock<std::mutex> lock(mLoadMutex);
    mLoadedCv.wait(lock, [this] { return mLoaded; });
    if (!mLoadError.empty()) throw InputError(mLoadError);
}

bool ViewStudy::loaded() const
{
    std::lock_guard<std::mutex> lock(mLoadMutex);
    return mLoaded;
}

std::string ViewStudy::loadError() const
{
    std::lock_guard<std::mutex> lock(mLoadMutex);
    return mLoadError;
}

const RayScene& ViewStudy::scene() const
{
    waitLoaded();
    return *mScene;
}

openvdb::FloatGrid::ConstPtr ViewStudy::ctGrid() const
{
    waitLoaded();
    return mCt;
}

double ViewStudy::stepMm() const { return mCenterline.stepMm; }
double ViewStudy::arcMaxMm() const { return double(mCenterline.points.size() - 1) * mCenterline.stepMm; }

bool ViewStudy::sharesSurfaceWith(const ViewStudy& other) const
{
    waitLoaded();
    other.waitLoaded();
    return mScene == other.mScene;
}

std::size_t ViewStudy::sceneBytes() const
{
    waitLoaded();
    std::size_t bytes = std::size_t(mScene->vertexCount()) * 3 * sizeof(float) * 2 +  // vertices, normals
                        std::size_t(mScene->triangleCount()) * 3 * sizeof(uint32_t);
    if (mCt) bytes += std::size_t(mCt->memUsage());
    return bytes;
}

json ViewStudy::studyJson() const
{
    waitLoaded();
    json cl = json::array(), bridged = json::array();
    for (const auto& p : mCenterline.points) {
        cl.push_back(vec3(p.positionMm));
        bridged.push_back(p.bridged);
    }
    json missed = json::array();
    if (mCoverage.is_object() && mCoverage.contains("flyover")) {
        const json& fo = mCoverage["flyover"];
        if (fo.contains("both_cameras") && fo["both_cameras"].contains("missed_regions")) {
            int id = 0;
            for (const auto& r : fo["both_cameras"]["missed_regions"])
                missed.push_back(json{{"id", id++},
                                      {"area_mm2", r.value("area_mm2", 0.0)},
                                      {"centroid_mm", r.value("centroid_mm", json::array())},
                                      {"arc_mm", r.value("arc_mm", 0.0)}});
        }
    }
    json j{{"world_frame", WORLD_FRAME},
           {"study", fs::absolute(mDir).string()},
           {"length_mm", arcMaxMm()},
           {"step_mm", stepMm()},
           {"arc_min_mm", 0},
           {"arc_max_mm", arcMaxMm()},
           {"default_px", std::min(mParams.heightPx, maxPx())},
           {"max_px", maxPx()},
           {"fov_deg", mParams.fovDeg},
           {"roll_deg", mParams.rollDeg},
           {"direction", mParams.direction},
           {"clip_offset_fraction", mParams.clipOffsetFraction},
           {"overview_px", mParams.overviewPx},
           {"has_ct", hasCt()},
           {"ct", nullptr},
           {"centerline", cl},
           {"bridged", bridged},
           {"missed_regions", missed},
           {"polyps", json::array()},
           {"triangles", mScene->triangleCount()},
           {"scene_bytes", sceneBytes()}};
    if (hasCt()) {
        j["ct"] = json{{"bounds_mm", json::array({vec3(mCtMin), vec3(mCtMax)})},
                       {"spacing_mm", json::array({mCtSpacing[0], mCtSpacing[1], mCtSpacing[2]})},
                       {"default_window", 1500},
                       {"default_level", -300}};
    }
    return j;
}

std::size_t ViewStudy::indexOfArc(double arcMm) const
{
    if (!std::isfinite(arcMm)) throw ParameterError("arc_mm: must be a finite number");
    const double maxArc = arcMaxMm();
    // Half a step of slack at both ends: the nearest point is still on the path.
    if (arcMm < -0.5 * stepMm() || arcMm > maxArc + 0.5 * stepMm())
        throw RangeError("arc_mm: " + std::to_string(arcMm) + " is outside the path [0, " + std::to_string(maxArc) + "]");
    const long long i = std::llround(arcMm / stepMm());
    return std::size_t(std::clamp<long long>(i, 0, (long long)mCenterline.points.size() - 1));
}

FlyoverParams ViewStudy::flyoverParams(const ViewPose& pose) const
{
    FlyoverParams fp = flyoverParamsOf(mParams);
    fp.rollDeg = pose.rollDeg;
    fp.leftToRight = pose.direction != "left";
    if (pose.clipOffsetFraction >= 0) {
        fp.clipOffsetFraction = pose.clipOffsetFraction;
        fp.clipOffsetMm = -1.0;
    }
    return fp;
}

RenderOptions ViewStudy::renderOptions(int px) const
{
    RenderOptions ro = frameOptionsOf(mParams);
    ro.widthPx = ro.heightPx = px;
    return ro;
}

LoopWindow ViewStudy::loopWindow(std::size_t index, const std::string& mode) const
{
    LoopWindow w;
    waitLoaded();
    if (mOwners.empty() || mode == "flythrough") return w;
    w.ownerArcMm = &mOwners;
    w.reachMm = mParams.loopReachMm;
    w.arcMm = double(index) * stepMm();
    return w;
}

double ViewStudy::frameRadius(std::size_t index, double rollDeg) const
{
    const long long rollKey = std::llround(rollDeg * 1e6);
    {
        std::lock_guard<std::mutex> lock(mCacheMutex);
        const auto it = mRadiusCache.find({index, rollKey});
        if (it != mRadiusCache.end()) return it->second;
    }
    // flyoverFrameRadii's value at `index` depends only on the points within the running
    // maximum's window plus the Gaussian's half-width of it, so the radii of that stretch alone
    // give the very same number as the render stage's pass over the whole centerline.
    const FrameRadiusOptions options;
    const double step = mCenterline.stepMm;
    const std::size_t reach =
        std::size_t(std::lround(options.windowMm / step)) + std::size_t(std::ceil(3 * options.smoothMm / step)) + 1;
    const std::size_t n = mCenterline.points.size();
    const std::size_t lo = index > reach ? index - reach : 0, hi = std::min(n - 1, index + reach);
    Centerline part;
    part.stepMm = step;
    part.points.assign(mCenterline.points.begin() + long(lo), mCenterline.points.begin() + long(hi) + 1);
    FlyoverParams fp;
    fp.fovDeg = mParams.fovDeg;
    fp.rollDeg = rollDeg;
    const double r = flyoverFrameRadii(scene(), part, fp, options)[index - lo];
    std::lock_guard<std::mutex> lock(mCacheMutex);
    if (mRadiusCache.size() > 100000) mRadiusCache.clear();
    mRadiusCache[{index, rollKey}] = r;
    return r;
}

std::array<Camera, 2> ViewStudy::cameras(const ViewPose& pose, std::size_t* indexOut) const
{
    const std::size_t i = indexOfArc(pose.arcMm);
    if (indexOut) *indexOut = i;
    const CenterlinePoint& p = mCenterline.points[i];
    if (pose.mode == "flythrough") {
        const bool left = pose.direction == "left";
        return {flythroughCamera(p, !left, mParams.flythroughFovDeg), flythroughCamera(p, left, mParams.flythroughFovDeg)};
    }
    return flyoverCameras(p, flyoverParams(pose), frameRadius(i, pose.rollDeg));
}

PairRender ViewStudy::renderPair(const ViewPose& pose) const
{
    PairRender out;
    out.cameras = cameras(pose, &out.centerlineIndex);
    RenderOptions ro = renderOptions(pose.px);
    ro.loop = loopWindow(out.centerlineIndex, pose.mode);
    const RayScene& sc = scene();
    RgbImage views[2];
    LoopCounts counts[2];
    tbb::parallel_for(0, 2, [&](int k) {
        renderView(sc, out.cameras[std::size_t(k)], ro, views[k], nullptr, &counts[k]);
    });
    out.image = sideBySide(views[0], views[1]);
    const CenterlinePoint& p = mCenterline.points[out.centerlineIndex];
    out.poseJson = json{{"arc_mm", double(out.centerlineIndex) * stepMm()},
                        {"requested_arc_mm", pose.arcMm},
                        {"centerline_index", out.centerlineIndex},
                        {"centerline_point_mm", vec3(p.positionMm)},
                        {"bridged", p.bridged},
                        {"roll_deg", pose.rollDeg},
                        {"direction", pose.direction},
                        {"mode", pose.mode},
                        {"clip_offset_fraction", pose.clipOffsetFraction < 0 ? mParams.clipOffsetFraction
                                                                             : pose.clipOffsetFraction},
                        {"px", pose.px},
                        {"loop_reach_mm", ro.loop.active() ? json(ro.loop.reachMm) : json(nullptr)},
                        {"foreign_wall_share",
                         ro.loop.active()
                             ? json(LoopCounts{counts[0].wallPixels + counts[1].wallPixels,
                                               counts[0].passedPixels + counts[1].passedPixels}
                                        .passedShare())
                             : json(nullptr)},
                        {"world_frame", WORLD_FRAME},
                        {"cameras", json::array({cameraJson(out.cameras[0]), cameraJson(out.cameras[1])})}};
    return out;
}

PickResult ViewStudy::pick(const ViewPose& pose, int view, double x, double y) const
{
    if (view != 0 && view != 1) throw ParameterError("view: must be 0 or 1");
    if (!(x >= 0 && x <= pose.px) || !(y >= 0 && y <= pose.px))
        throw RangeError("x, y: must lie in [0, px] = [0, " + std::to_string(pose.px) + "]");
    std::size_t index = 0;
    const Camera cam = cameras(pose, &index)[std::size_t(view)];
    const Vec3d dir = pixelDirection(cam, pose.px, pose.px, x, y);
    const RayHit h = scene().intersect(cam.position, dir, cam.nearMm, std::numeric_limits<double>::infinity(),
                                       mParams.ost, loopWindow(index, pose.mode));
    PickResult r;
    if (!h.hit) return r;
    r.hit = true;
    r.pointMm = cam.position + dir * h.t;
    r.distanceMm = distance(r.pointMm, cam.position);
    r.triangle = h.primId;
    return r;
}

std::size_t ViewStudy::nearestIndex(const Vec3d& q) const
{
    std::size_t best = 0, bestOpen = std::numeric_limits<std::size_t>::max();
    double d = std::numeric_limits<double>::infinity(), dOpen = d;
    for (std::size_t i = 0; i < mCenterline.points.size(); ++i) {
        const double di = distance(mCenterline.points[i].positionMm, q);
        if (di < d) d = di, best = i;
        if (!mCenterline.points[i].bridged && di < dOpen) dOpen = di, bestOpen = i;
    }
    return bestOpen != std::numeric_limits<std::size_t>::max() ? bestOpen : best;
}

LocateResult ViewStudy::locate(const Vec3d& q, int px, const std::string& direction) const
{
    const std::size_t i = nearestIndex(q);
    const CenterlinePoint& p = mCenterline.points[i];
    const Vec3d t = normalize(p.tangent);
    const Vec3d n0 = normalize(p.normal - t * dot(p.normal, t));
    const Vec3d b = cross(t, n0);
    const Vec3d rel = q - p.positionMm;
    Vec3d d = rel - t * dot(rel, t);
    if (!(length(d) > 1e-6)) d = n0;  // on the centerline itself: any roll frames it
    // Camera 0 looks along -n (it sees the wall on the -n side), camera 1 along +n: the roll
    // that turns n onto -d centres the point in view 0, onto +d in view 1. Take the smaller roll.
    const double rollView1 = std::atan2(dot(d, b), dot(d, n0)) * 180.0 / PI;
    double rollView0 = rollView1 + 180.0;
    if (rollView0 > 180.0) rollView0 -= 360.0;
    LocateResult r;
    r.view = std::fabs(rollView0) <= std::fabs(rollView1) ? 0 : 1;
    r.pose.arcMm = double(i) * stepMm();
    r.pose.rollDeg = r.view == 0 ? rollView0 : rollView1;
    r.pose.direction = direction;
    r.pose.mode = "flyover";
    r.pose.clipOffsetFraction = -1;
    r.pose.px = px;
    r.centerlineIndex = i;
    const Camera cam = cameras(r.pose)[std::size_t(r.view)];
    const Vec3d v = q - cam.position;
    const double z = dot(v, cam.forward);
    if (!(z > 0)) throw InputError("locate: the point lies behind the camera");  // cannot happen for d != 0
    const double tanHalf = std::tan(0.5 * cam.fovDeg * PI / 180.0);
    r.x = (dot(v, cam.right) / z / tanHalf + 1.0) * 0.5 * px;
    r.y = (1.0 - dot(v, cam.up) / z / tanHalf) * 0.5 * px;
    return r;
}

Camera ViewStudy::overviewCamera() const
{
    const CanonicalView& anterior = canonicalViews()[0];
    return flyover::overviewCamera(scene().boundsMin(), scene().boundsMax(), anterior.viewDir, anterior.up, 30.0);
}

RgbImage ViewStudy::overview(int px, double markerArcMm, const std::vector<OverviewMarker>& marks) const
{
    std::shared_ptr<const RgbImage> base;
    {
        std::lock_guard<std::mutex> lock(mCacheMutex);
        const auto it = mOverviewCache.find(px);
        if (it != mOverviewCache.end()) base = it->second;
    }
    const Camera cam = overviewCamera();
    if (!base) {
        // As the render stage renders overview.png.
        RenderOptions ov;
        ov.widthPx = ov.heightPx = px;
        ov.ost = mParams.ost;
        ov.supersample = std::max(mParams.supersample, 2);
        ov.smoothShading = mParams.smoothShading;
        ov.depthCue = mParams.depthCue;
        base = std::make_shared<const RgbImage>(renderView(scene(), cam, ov));
        std::lock_guard<std::mutex> lock(mCacheMutex);
        if (mOverviewCache.size() >= 4) mOverviewCache.clear();
        mOverviewCache[px] = base;
    }
    RgbImage image = *base;
    for (const OverviewMarker& m : marks) drawMarker(image, cam, m);
    if (markerArcMm >= 0) {
        const CenterlinePoint& p = mCenterline.points[indexOfArc(markerArcMm)];
        drawMarker(image, cam, OverviewMarker{p.positionMm, std::max(p.radiusMm, 1.0)});
    }
    return image;
}

ViewStudy::OverviewPick ViewStudy::overviewPick(int px, double x, double y) const
{
    if (!(x >= 0 && x <= px) || !(y >= 0 && y <= px))
        throw RangeError("x, y: must lie in [0, px] = [0, " + std::to_string(px) + "]");
    const Camera cam = overviewCamera();
    const Vec3d dir = pixelDirection(cam, px, px, x, y);
    const RayHit h = scene().intersect(cam.position, dir, cam.nearMm, std::numeric_limits<double>::infinity(),
                                       mParams.ost);
    OverviewPick r;
    if (!h.hit) return r;
    r.hit = true;
    r.pointMm = cam.position + dir * h.t;
    r.arcMm = double(nearestIndex(r.pointMm)) * stepMm();
    return r;
}

SliceImage ViewStudy::slice(const std::string& plane, const Vec3d& q, double window, double level) const
{
    if (!hasCt()) throw InputError("slice: this study has no CT (a mask-only study); start the viewer with --ct FILE");
    const openvdb::FloatGrid::ConstPtr grid = ctGrid();
    const double spacing = std::min({mCtSpacing[0], mCtSpacing[1], mCtSpacing[2]});
    // The whole CT's extent in the plane, at most 1024 pixels a side: a coarser pixel for
    // larger scans.
    const Vec3d extent = mCtMax - mCtMin;
    const double colExtent = plane == "sagittal" ? extent.y : extent.x;
    const double rowExtent = plane == "axial" ? extent.y : extent.z;
    const double pixel = std::max(spacing, std::max(colExtent, rowExtent) / 1023.0);
    return sampleSlice(*grid, sliceGeometry(plane, q, mCtMin, mCtMax, pixel), window, level);
}

} // namespace flyover
