#include "pipeline/stage_context.h"

#include "pipeline/artifact_io.h"
#include "render/camera.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "volume/error.h"

#include <tbb/parallel_for.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <unistd.h>

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

json cameraJson(const Camera& c)
{
    return json{{"position_mm", vec3Json(c.position)}, {"forward", vec3Json(c.forward)},
                {"up", vec3Json(c.up)},                {"right", vec3Json(c.right)},
                {"fov_deg", c.fovDeg},                 {"near_mm", c.nearMm}};
}

} // namespace

json runRender(StudyRun& run, Progress* progress)
{
    if (!run.state.mesh) run.state.mesh = readMesh(run.path("surface.ply"));
    if (!run.state.centerline)
        run.state.centerline =
            centerlineFromJson(readJson(run.path("centerline.json")), run.path("centerline.json"));
    const RenderParams& rp = run.opt.params.render;
    const Centerline& cl = *run.state.centerline;
    if (cl.points.empty()) throw InputError(run.path("centerline.json") + ": the centerline is empty");

    RayScene scene(*run.state.mesh);

    // Overview (thesis V.C): the whole colon from the front (anterior, looking towards +y in
    // LPS), head up, so the patient's right is on the image's left as in radiology.
    RenderOptions ov;
    ov.widthPx = ov.heightPx = rp.overviewPx;
    ov.ost = rp.ost;
    ov.supersample = std::max(rp.supersample, 2);
    const Camera overview = overviewCamera(scene.boundsMin(), scene.boundsMax(), {0, 1, 0}, {0, 0, 1}, 30.0);
    writePng(run.path("overview.png"), renderView(scene, overview, ov));

    // Fly-over frame pairs every frameStepMm along the centerline.
    FlyoverParams fp;
    fp.fovDeg = rp.fovDeg;
    fp.rollDeg = rp.rollDeg;
    fp.leftToRight = rp.direction == "right";
    fp.clipOffsetFraction = rp.clipOffsetFraction;
    fp.clipOffsetMm = rp.clipOffsetMm;
    RenderOptions ro;
    ro.widthPx = rp.widthPx;
    ro.heightPx = rp.heightPx;
    ro.ost = rp.ost;
    ro.supersample = rp.supersample;

    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    std::vector<std::size_t> indices;
    for (double s = 0; ; s += rp.frameStepMm) {
        const auto i = static_cast<std::size_t>(std::llround(s / step));
        if (i >= cl.points.size()) break;
        indices.push_back(i);
    }

    // Frames go to a fresh folder that replaces frames/ only when complete.
    const fs::path tmpDir = run.dir / (".tmp-" + std::to_string(::getpid()) + "-frames");
    fs::remove_all(tmpDir);
    fs::create_directories(tmpDir);
    std::vector<json> poses(indices.size());
    const auto t0 = std::chrono::steady_clock::now();
    std::atomic<std::size_t> done{0};
    tbb::parallel_for(std::size_t(0), indices.size(), [&](std::size_t f) {
        const CenterlinePoint& p = cl.points[indices[f]];
        const auto cams = flyoverCameras(p, fp);
        const RgbImage a = renderView(scene, cams[0], ro);
        const RgbImage b = renderView(scene, cams[1], ro);
        char name[32];
        std::snprintf(name, sizeof name, "pair_%04zu.png", f);
        writePng((tmpDir / name).string(), sideBySide(a, b));
        poses[f] = json{{"frame", f},
                        {"file", name},
                        {"centerline_index", indices[f]},
                        {"arc_mm", indices[f] * step},
                        {"centerline_point_mm", vec3Json(p.positionMm)},
                        {"radius_mm", p.radiusMm},
                        {"cameras", json::array({cameraJson(cams[0]), cameraJson(cams[1])})}};
        reportProgress(progress, double(++done) / indices.size(), "fly-over frame pairs");
    });
    const double renderSeconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    writeJson((tmpDir / "poses.json").string(),
              json{{"schema", "flyover.poses/1"},
                   {"world_frame", WORLD_FRAME},
                   {"image_size_px", {rp.widthPx, rp.heightPx}},
                   {"layout", "pair images: camera 0 left, camera 1 right"},
                   {"ost", rp.ost},
                   {"frames", poses}});
    const fs::path frames = run.dir / "frames";
    const fs::path old = run.dir / (".tmp-" + std::to_string(::getpid()) + "-frames-old");
    fs::remove_all(old);
    if (fs::exists(frames)) fs::rename(frames, old);
    fs::rename(tmpDir, frames);
    fs::remove_all(old);

    return json{{"frame_pairs", indices.size()},
                {"triangles", scene.triangleCount()},
                {"frame_pairs_seconds", renderSeconds},
                {"overview_camera", cameraJson(overview)}};
}

} // namespace flyover
