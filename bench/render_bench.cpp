// render_bench: the fly-over renderer measured on a phantom.
//
//   render_bench [--mode speed|coverage|sweep|quads|marker] [--study DIR [--truth FILE]] [--size full|medium|small]
//                [--seed N] [--px 512] [--threads 2] [--runs 5] [--positions 60]
//                [--pairing coplanar|compact] [--embree-config STRING]
//
// speed     frame pairs/s and Mrays/s of the fly-over next to the bare Embree throughput
//           (16-wide coherent packets, no filter, no shading) for the same rays, for each OST
//           method, with and without Embree's robust mode; PNG encoding; scene build; and, with
//           --study, the time from the cached surface and centerline to the first saved pair
//           (the frames step itself, through the pipeline, on a copy of the study: the
//           study is never written).
// coverage  coverage fractions against the coverage rays' resolution and step (convergence).
// marker    the coverage step's marking (ViewMarker, the render stage's coverage_px and OST) on
//           --positions centerline points, evenly spread, four views each (both fly-over
//           cameras, the fly-through both ways): process CPU seconds of the views traced with
//           hits only and with the footprint walk, alternated run by run, the walk's share
//           (their difference) per ray, and a digest of the flagged triangles, the same for
//           two builds when they mark the same triangles. Use --threads 1 for the clearest figures.
// sweep     the clip offset sweep: coverage, polyp visibility (also on the cutting line) and
//           occlusion by other loops of colon for each offset (needs the truth polyps).
// quads     Embree's traversal of the surface as triangles (RTC_GEOMETRY_TYPE_TRIANGLE, what
//           RayScene builds) against the same surface as quads (RTC_GEOMETRY_TYPE_QUAD: edge-
//           adjacent triangles paired, the most nearly coplanar pairs first, an unpaired one as
//           the degenerate quad (a, b, c, c)), both robust, BVH MEDIUM, the same 16-wide
//           coherent packets of the fly-over cameras, alternated view by view.
//
// Without --study the phantom is generated and taken through ingest, segment, centerline and
// mesh in memory (about a minute for the full size); with --study the study's surface.ply and
// centerline.json are read (and --truth names the phantom's truth JSON for the polyps).
// Timings are medians over --runs runs, interleaved so that load on a shared machine hits
// every variant alike; "CPU-normalised" figures divide the work by the process CPU time per
// thread, which is what the figures would be on otherwise idle cores.

#include "volume/seconds_since.h"
#include "colon/phantom.h"
#include "pipeline/artifact_io.h"
#include "pipeline/stage_command.h"
#include "colon/phantom_io.h"
#include "colon/render_settings.h"
#include "colon/colon_study.h"
#include "render/camera.h"
#include "render/coverage.h"
#include "render/flyover_path.h"
#include "render/ray_scene.h"
#include "render/view_rays.h"
#include "render/render_view.h"
#include "surface/extract_surface.h"
#include "colon/centerline.h"
#include "volume/ingest.h"
#include "colon/segment.h"

#include <embree3/rtcore.h>
#include <tbb/blocked_range2d.h>
#include <tbb/global_control.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <unistd.h>
#include <unordered_map>
#include <xmmintrin.h>
#include <pmmintrin.h>
#include <limits>
#include <cmath>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

using Clock = std::chrono::steady_clock;


/// CPU seconds used by the whole process so far (all threads).
double processCpuSeconds()
{
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

/// Wall and CPU seconds of one piece of work.
struct Timing {
    double wall = 0, cpu = 0;
};
Timing measure(const std::function<void()>& work)
{
    const double c0 = processCpuSeconds();
    const auto t0 = Clock::now();
    work();
    return {secondsSince(t0), processCpuSeconds() - c0};
}

double median(std::vector<double> v)
{
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n == 0 ? 0.0 : (n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]));
}

struct Args {
    std::string mode = "speed";
    std::string study, truth;
    std::string size = "full";
    uint64_t seed = 1;
    int px = 512;
    int threads = 2;
    int runs = 5;
    int positions = 60;
    std::string pairing = "coplanar";
    std::string embreeConfig;  ///< rtcNewDevice's config string (--mode quads)
};

Args parseArgs(int argc, char** argv)
{
    Args a;
    for (int i = 1; i < argc; ++i) {
        const std::string k = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) throw std::runtime_error(k + " needs a value");
            return argv[++i];
        };
        if (k == "--mode") a.mode = value();
        else if (k == "--study") a.study = value();
        else if (k == "--truth") a.truth = value();
        else if (k == "--size") a.size = value();
        else if (k == "--seed") a.seed = std::stoull(value());
        else if (k == "--px") a.px = std::stoi(value());
        else if (k == "--threads") a.threads = std::stoi(value());
        else if (k == "--runs") a.runs = std::stoi(value());
        else if (k == "--positions") a.positions = std::stoi(value());
        else if (k == "--pairing") a.pairing = value();
        else if (k == "--embree-config") a.embreeConfig = value();
        else throw std::runtime_error("unknown option " + k + " (see the comment at the top of render_bench.cpp)");
    }
    if (a.mode != "speed" && a.mode != "coverage" && a.mode != "sweep" && a.mode != "quads" && a.mode != "marker")
        throw std::runtime_error("--mode must be speed, coverage, sweep, quads or marker");
    if (a.pairing != "coplanar" && a.pairing != "compact")
        throw std::runtime_error("--pairing must be coplanar or compact");
    if (!(a.runs >= 1 && a.threads >= 1 && a.px >= 8 && a.positions >= 1))
        throw std::runtime_error("--runs, --threads, --positions must be >= 1 and --px >= 8");
    return a;
}

struct Subject {
    TriMesh mesh;
    Centerline centerline;
    std::vector<PhantomPolyp> polyps;
};

Subject load(const Args& a)
{
    Subject s;
    if (!a.study.empty()) {
        s.mesh = readMesh((fs::path(a.study) / "surface.ply").string());
        const std::string clPath = (fs::path(a.study) / "centerline.json").string();
        s.centerline = centerlineFromJson(readJson(clPath), clPath);
        if (!a.truth.empty()) s.polyps = phantomTruthFromJson(readJson(a.truth), a.truth).polyps;
        return s;
    }
    const auto t0 = Clock::now();
    PhantomParams pp;
    pp.size = parsePhantomSize(a.size);
    pp.seed = a.seed;
    const Phantom phantom = makePhantom(pp);
    Image3<float> image;
    image.geometry = phantom.ct.geometry;
    image.voxels.assign(phantom.ct.voxels.begin(), phantom.ct.voxels.end());
    const auto hu = ingestImage(image, IngestParams{});
    const LumenSegmentation lumen = segmentLumen(*hu, SegmentParams{});
    s.centerline = extractCenterline(*lumen.sdf, CenterlineParams{});
    s.mesh = extractSurface(*lumen.sdf, MeshParams{});
    s.polyps = phantom.truth.polyps;
    std::printf("generated the %s phantom (seed %llu), its surface and centerline in %.1f s\n", a.size.c_str(),
                static_cast<unsigned long long>(a.seed), secondsSince(t0));
    return s;
}

/// Fly-over camera pairs at `count` positions spread evenly along the centerline.
std::vector<std::array<Camera, 2>> flyoverPath(const RayScene& scene, const Centerline& cl, int count,
                                               const FlyoverParams& fp)
{
    const std::vector<double> frame = flyoverFrameRadii(scene, cl, fp);
    std::vector<std::array<Camera, 2>> cams;
    const std::size_t n = cl.points.size();
    for (int k = 0; k < count; ++k) {
        const std::size_t i = std::min(n - 1, std::size_t((double(k) + 0.5) / count * double(n)));
        cams.push_back(flyoverCameras(cl.points[i], fp, frame[i]));
    }
    return cams;
}

// ------------------------------------------------------------------------------------ speed

void benchThroughput(const Args& a, const Subject& s)
{
    const auto path = flyoverPath(RayScene(s.mesh), s.centerline, a.positions, FlyoverParams{});
    const double rays = 2.0 * a.px * a.px * double(path.size());
    const double pairs = double(path.size());
    std::printf("\nfly-over at %zu positions spread along the centerline, default cameras (fov 90, clip offset "
                "0.5 D), %d x %d per view, one pair after the other (each view parallel over tiles)\n",
                path.size(), a.px, a.px);

    for (const bool robust : {true, false}) {
        SceneOptions so;
        so.robust = robust;
        const RayScene scene(s.mesh, so);
        struct Variant {
            const char* name;
            bool bare;
            OstMethod method;
            bool ost;
            bool smooth;
            std::vector<double> wall, cpu;
        };
        std::vector<Variant> variants = {
            {"bare Embree (16-wide coherent, no filter/shading)", true, OstMethod::Auto, false, false, {}, {}},
            {"fly-over OST auto, smooth  [default]", false, OstMethod::Auto, true, true, {}, {}},
            {"fly-over OST filter only, smooth", false, OstMethod::Filter, true, true, {}, {}},
            {"fly-over OST retrace only, smooth", false, OstMethod::Retrace, true, true, {}, {}},
            {"fly-over OST auto, flat", false, OstMethod::Auto, true, false, {}, {}},
            {"fly-over plain (--no-ost), smooth", false, OstMethod::Auto, false, true, {}, {}}};
        for (int r = 0; r < a.runs; ++r) {
            for (Variant& v : variants) {
                RenderOptions ro;
                ro.widthPx = ro.heightPx = a.px;
                ro.ost = v.ost;
                ro.ostMethod = v.method;
                ro.smoothShading = v.smooth;
                ro.depthCue = true;
                ro.depthCueRangeMm = 60.0;
                RgbImage left, right;
                uint64_t hits = 0;
                const Timing t = measure([&] {
                    for (const auto& pair : path) {
                        if (v.bare) {
                            for (const Camera& c : pair) hits += traceBare(scene, c, a.px, a.px);
                        } else {
                            renderView(scene, pair[0], ro, left);
                            renderView(scene, pair[1], ro, right);
                        }
                    }
                });
                if (v.bare && hits == 0) std::printf("  (no ray hit: check the input)\n");
                v.wall.push_back(t.wall);
                v.cpu.push_back(t.cpu);
            }
        }
        std::printf("\nscene: %u triangles, Embree robust mode %s\n", scene.triangleCount(), robust ? "on" : "off");
        std::printf("  %-52s %8s %8s %8s | %-s\n", "median of runs", "Mrays/s", "pairs/s", "of bare",
                    "CPU-normalised: Mrays/s  pairs/s  of bare");
        const double bareWall = median(variants[0].wall), bareCpu = median(variants[0].cpu);
        for (const Variant& v : variants) {
            const double w = median(v.wall), c = median(v.cpu) / a.threads;
            std::printf("  %-52s %8.1f %8.1f %7.0f%% | %14.1f %8.1f %7.0f%%\n", v.name, rays / w * 1e-6, pairs / w,
                        100.0 * bareWall / w, rays / c * 1e-6, pairs / c, 100.0 * bareCpu / median(v.cpu));
        }
    }
}

void benchSceneAndPng(const Args& a, const Subject& s)
{
    // Scene build from plain arrays (what the render stage does with a cached surface.ply).
    std::vector<float> xyz;
    for (const auto v : s.mesh.vertices())
        for (int k = 0; k < 3; ++k) xyz.push_back(s.mesh.point(v)[k]);
    std::vector<uint32_t> tris;
    for (const auto f : s.mesh.faces())
        for (const auto v : s.mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
    std::vector<double> wall, cpu;
    for (int r = 0; r < a.runs; ++r) {
        const Timing t = measure([&] { const RayScene scene(xyz, tris); });
        wall.push_back(t.wall);
        cpu.push_back(t.cpu);
    }
    std::printf("\nscene build from arrays (copy, vertex normals, BVH MEDIUM, robust): %.3f s wall, %.3f s CPU "
                "(%.3f s on %d idle cores)\n",
                median(wall), median(cpu), median(cpu) / a.threads, a.threads);

    const RayScene scene(s.mesh);
    const auto path = flyoverPath(scene, s.centerline, std::min(a.positions, 24), FlyoverParams{});
    RenderOptions ro;
    ro.widthPx = ro.heightPx = a.px;
    std::vector<RgbImage> images;
    for (const auto& pair : path) images.push_back(sideBySide(renderView(scene, pair[0], ro), renderView(scene, pair[1], ro)));
    const fs::path dir = fs::temp_directory_path() / ("render_bench_png_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    std::vector<double> one, all;
    for (int r = 0; r < a.runs; ++r) {
        one.push_back(measure([&] {
                          for (std::size_t i = 0; i < images.size(); ++i)
                              writePng((dir / ("a" + std::to_string(i) + ".png")).string(), images[i]);
                      }).wall);
        all.push_back(measure([&] {
                          tbb::parallel_for(std::size_t(0), images.size(), [&](std::size_t i) {
                              writePng((dir / ("b" + std::to_string(i) + ".png")).string(), images[i]);
                          });
                      }).wall);
    }
    fs::remove_all(dir);
    std::printf("PNG encode + atomic write of %d x %d pair images: %.1f pairs/s on one thread, %.1f pairs/s on %d\n",
                images.front().width, images.front().height, double(images.size()) / median(one),
                double(images.size()) / median(all), a.threads);
}

/// The frames step itself on a cached study: surface.ply and centerline.json on disk, frames
/// forced. Runs on a copy of the study (copyStudy), never in the user's study: a benchmark's
/// parameters must not leave their frames and manifest there.
void benchFirstPair(const Args& a)
{
    const fs::path copy = fs::temp_directory_path() / ("flyover-render-bench-" + std::to_string(::getpid()));
    fs::remove_all(copy);
    copyStudy(a.study, copy.string());
    struct RemoveCopy {
        fs::path p;
        ~RemoveCopy() { std::error_code ec; fs::remove_all(p, ec); }
    } removeCopy{copy};
    const nlohmann::json manifest = readJson((copy / "manifest.json").string());
    RunOptions o;
    o.ctPath = recordedInput(manifest, "input");  // "" for a mask-only study
    o.maskPath = recordedInput(manifest, "mask");
    o.studyDir = copy.string();
    // The study's own parameters for the stages before the frames, so that they are reused.
    for (const auto& st : manifest.at("stages")) {
        const std::string stage = st.value("stage", "");
        if ((stage == "ingest" || stage == "segment" || stage == "centerline" || stage == "mesh") &&
            st.contains("parameters") && stageVersion(stage) == st.value("version", -1))
            applyParamsJson(o.params, nlohmann::json{{stage, st.at("parameters")}}, "manifest.json");
    }
    o.untilStage = "frames";
    o.forceStage = "frames";
    o.params.render.frameStepMm = 400;
    o.params.render.widthPx = o.params.render.heightPx = a.px;
    std::vector<double> total;
    std::map<std::string, std::vector<double>> parts;
    for (int r = 0; r < a.runs; ++r) {
        const nlohmann::json m = runPipeline(o);
        for (const auto& st : m.at("stages"))
            if (st.at("stage") == "frames") {
                total.push_back(st.at("report").at("first_pair_seconds").get<double>());
                for (const auto& [k, v] : st.at("report").at("first_pair_breakdown_seconds").items())
                    parts[k].push_back(v.get<double>());
            }
    }
    std::printf("\ntime from the cached surface and centerline to the first saved pair (frames step, %d x %d "
                "per view): %.3f s median of %d (",
                a.px, a.px, median(total), a.runs);
    const char* sep = "";
    for (const auto& [k, v] : parts) {
        std::printf("%s%s %.3f", sep, k.c_str(), median(v));
        sep = ", ";
    }
    std::printf(")\n");
}

// --------------------------------------------------------------------------------- coverage

void benchCoverage(const Subject& s)
{
    const RayScene scene(s.mesh);
    std::printf("\ncoverage against the coverage rays' resolution and step (%u triangles)\n", scene.triangleCount());
    std::printf("  %9s %7s %8s | %9s %10s %10s %9s | %8s %7s\n", "rule", "view_px", "step_mm", "fly-over", "FT forward",
                "FT backward", "FT 2-way", "rays (M)", "seconds");
    for (const bool footprint : {true, false})
    for (const double step : {1.0, 2.0, 4.0})
        for (const int px : {32, 48, 64, 96, 144, 192, 288, 384}) {
            if (step > 1.0 && px != 64 && px != 96) continue;
            if (!footprint && px < 96) continue;
            CoverageParams cp;
            cp.viewPx = px;
            cp.stepMm = step;
            cp.footprint = footprint;
            CoverageResult c;
            const Timing t = measure([&] { c = computeCoverage(scene, s.centerline, cp); });
            std::printf("  %s %7d %8.1f | %8.3f%% %9.3f%% %10.3f%% %8.3f%% | %8.1f %7.1f\n",
                        footprint ? "footprint" : "hit only ", px, step,
                        100 * c.flyover.fraction, 100 * c.flythroughForward.fraction,
                        100 * c.flythroughBackward.fraction, 100 * c.flythroughTwoWay.fraction, double(c.rays) * 1e-6,
                        t.wall);
        }
}

// ----------------------------------------------------------------------------------- marker

void benchMarker(const Args& a, const Subject& s)
{
    const RayScene scene(s.mesh);
    const RenderParams rp;
    const FlyoverParams fp = flyoverParamsOf(rp);
    const Centerline& cl = s.centerline;
    const std::vector<double> frame = flyoverFrameRadii(scene, cl, fp);
    std::vector<Camera> cams;
    const std::size_t n = std::min(cl.points.size(), std::size_t(a.positions));
    for (std::size_t k = 0; k < n; ++k) {
        const std::size_t i = n > 1 ? k * (cl.points.size() - 1) / (n - 1) : 0;
        for (const Camera& c : flyoverCameras(cl.points[i], fp, frame[i])) cams.push_back(c);
        cams.push_back(flythroughCamera(cl.points[i], true, rp.flythroughFovDeg));
        cams.push_back(flythroughCamera(cl.points[i], false, rp.flythroughFovDeg));
    }
    ViewMarker hitsOnly(scene, rp.coveragePx, false), walk(scene, rp.coveragePx, true);
    std::vector<uint8_t> seen(scene.triangleCount(), 0);
    uint64_t rays = 0;
    auto markAll = [&](ViewMarker& m) {
        const double c0 = processCpuSeconds();
        rays = 0;
        for (const Camera& c : cams) rays += m.mark(c, rp.ost, seen.data());
        return processCpuSeconds() - c0;
    };
    std::vector<double> hitsCpu, walkCpu;
    markAll(walk);  // warm-up (first touch of the scene and the marker's buffers)
    for (int r = 0; r < a.runs; ++r) {
        hitsCpu.push_back(markAll(hitsOnly));
        walkCpu.push_back(markAll(walk));
    }
    uint64_t digest = 1469598103934665603ull, flagged = 0;  // FNV-1a over the flags
    std::fill(seen.begin(), seen.end(), uint8_t(0));
    markAll(walk);
    for (const uint8_t f : seen) {
        digest = (digest ^ f) * 1099511628211ull;
        flagged += f;
    }
    const double hits = median(hitsCpu), both = median(walkCpu);
    std::printf("\ncoverage marking: %zu views (%zu centerline points), %d px, OST %s, %.2f M rays per run\n",
                cams.size(), n, rp.coveragePx, rp.ost ? "on" : "off", double(rays) * 1e-6);
    std::printf("  hits only      %7.3f CPU s (median of %d)\n", hits, a.runs);
    std::printf("  with footprint %7.3f CPU s\n", both);
    std::printf("  footprint walk %7.3f CPU s, %.0f ns per ray\n", both - hits, (both - hits) / double(rays) * 1e9);
    std::printf("  flagged %llu of %u triangles, digest %016llx\n", static_cast<unsigned long long>(flagged),
                scene.triangleCount(), static_cast<unsigned long long>(digest));
}

// ------------------------------------------------------------------------------------ sweep

struct PolypView {
    int bestPixels = 0;      ///< most polyp pixels in one view of the run near the polyp
    int cuttingPixels[2] = {0, 0};  ///< both views, rolled so the polyp lies on the cutting line
};

void benchSweep(const Args& a, const Subject& s)
{
    if (s.polyps.empty()) throw std::runtime_error("--mode sweep needs the truth polyps (--truth FILE, or no --study)");
    const RayScene scene(s.mesh);
    const Centerline& cl = s.centerline;
    const CenterlineLocator locator(cl);
    const TriangleGeometry geo = triangleGeometry(scene);
    // Arc position of every triangle (its nearest centerline point): a hit on a triangle whose
    // arc is far from the camera's is a hit on another loop of colon.
    std::vector<uint32_t> triangleArc(geo.centroidMm.size());
    tbb::parallel_for(std::size_t(0), geo.centroidMm.size(),
                      [&](std::size_t f) { triangleArc[f] = uint32_t(locator.nearest(geo.centroidMm[f])); });
    const double OTHER_LOOP_ARC_MM = 100.0;
    const int POLYP_PX = 256;
    const double POLYP_MARGIN_MM = 1.0;
    const double POLYP_WINDOW_MM = 40.0;

    std::printf("\nclip offset sweep: fov 90 (h = R, the framed half-width), roll 0 unless stated; offset = fraction * D(p), near plane "
                "at h - offset (fraction 0: on the centerline; 1: at the camera)\n");
    std::printf("coverage: fly-over, both cameras, 128 px every 1 mm. occlusion: pixels of fly-over views every "
                "2 mm at 128 px whose triangle's nearest centerline point is > %.0f mm of arc away from the "
                "camera's. polyps (%zu): pixels within r + %.0f mm of the centre, %d px views; best over the "
                "views within +-%.0f mm of the polyp; 'cut' = at the polyp's nearest point, roll putting it on "
                "the cutting line, better of the two views.\n",
                OTHER_LOOP_ARC_MM, s.polyps.size(), POLYP_MARGIN_MM, POLYP_PX, POLYP_WINDOW_MM);
    std::printf("  %8s | %9s | %10s %12s | %16s %18s\n", "fraction", "coverage", "other-loop", "frames >1%",
                "polyp px (min)", "cut polyp px (min)");

    for (const double fraction : {0.0, 0.1, 0.25, 0.4, 0.5, 0.75, 1.0}) {
        FlyoverParams fp;
        fp.clipOffsetFraction = fraction;
        CoverageParams cp;
        cp.viewPx = 128;
        cp.flyover = fp;
        cp.flythrough = false;
        const CoverageResult cov = computeCoverage(scene, cl, cp);
        const std::vector<double> frame = flyoverFrameRadii(scene, cl, fp);

        RenderOptions ro;
        ro.widthPx = ro.heightPx = 128;
        HitImage hits;
        uint64_t hitPixels = 0, otherPixels = 0;
        std::size_t frames = 0, occludedFrames = 0;
        for (std::size_t i = 0; i < cl.points.size(); i += 2) {
            uint64_t hitHere = 0, otherHere = 0;
            for (const Camera& c : flyoverCameras(cl.points[i], fp, frame[i])) {
                traceHits(scene, c, ro, hits);
                for (const uint32_t id : hits.primId) {
                    if (id >= triangleArc.size()) continue;
                    ++hitHere;
                    const double arcGap = std::fabs(double(triangleArc[id]) - double(i)) * cl.stepMm;
                    otherHere += arcGap > OTHER_LOOP_ARC_MM ? 1 : 0;
                }
            }
            hitPixels += hitHere;
            otherPixels += otherHere;
            ++frames;
            occludedFrames += (otherHere * 100 > hitHere) ? 1 : 0;
        }

        RenderOptions po;
        po.widthPx = po.heightPx = POLYP_PX;
        std::vector<PolypView> pv(s.polyps.size());
        std::string perPolyp;
        for (std::size_t k = 0; k < s.polyps.size(); ++k) {
            const PhantomPolyp& polyp = s.polyps[k];
            const double r = polyp.radiusMm + POLYP_MARGIN_MM;
            const std::size_t ip = locator.nearest(polyp.centerMm);
            const auto window = std::size_t(POLYP_WINDOW_MM / cl.stepMm);
            for (std::size_t i = ip > window ? ip - window : 0; i <= std::min(cl.points.size() - 1, ip + window); ++i)
                for (const Camera& c : flyoverCameras(cl.points[i], fp, frame[i])) {
                    traceHits(scene, c, po, hits);
                    pv[k].bestPixels = std::max(pv[k].bestPixels, countHitsWithin(c, hits, polyp.centerMm, r));
                }
            FlyoverParams rolled = fp;
            rolled.rollDeg = cuttingLineRollDeg(cl.points[ip], polyp.outwardDir);
            const auto cams = flyoverCameras(cl.points[ip], rolled, flyoverFrameRadii(scene, cl, rolled)[ip]);
            for (int v = 0; v < 2; ++v) {
                traceHits(scene, cams[std::size_t(v)], po, hits);
                pv[k].cuttingPixels[v] = countHitsWithin(cams[std::size_t(v)], hits, polyp.centerMm, r);
            }
            char buf[64];
            std::snprintf(buf, sizeof buf, "%s%.0f:%d/%d", k ? " " : "", polyp.radiusMm, pv[k].bestPixels,
                          std::max(pv[k].cuttingPixels[0], pv[k].cuttingPixels[1]));
            perPolyp += buf;
        }
        int minBest = 1 << 30, minCut = 1 << 30;
        for (const PolypView& v : pv) {
            minBest = std::min(minBest, v.bestPixels);
            minCut = std::min(minCut, std::max(v.cuttingPixels[0], v.cuttingPixels[1]));
        }
        std::printf("  %8.2f | %8.3f%% | %9.3f%% %11.1f%% | %16d %18d   [r mm: best/cut] %s\n", fraction,
                    100 * cov.flyover.fraction, 100.0 * double(otherPixels) / double(std::max<uint64_t>(1, hitPixels)),
                    100.0 * double(occludedFrames) / double(frames), minBest, minCut, perPolyp.c_str());
        std::fflush(stdout);
    }
}


// ------------------------------------------------------------------------------------ quads

/// Edge-adjacent triangles paired into quads (v0, v1, v2, v3) whose sub-triangles (v0, v1, v3)
/// and (v2, v3, v1) are the two triangles with their own orientation, greedily: `compact` takes
/// the pairs whose quad has the smallest bounding box first, otherwise the pairs whose unit
/// normals agree best come first. An unpaired triangle (a, b, c) becomes (a, b, c, c).
struct QuadPairing {
    std::vector<uint32_t> quads;  ///< 4 per quad
    std::size_t pairedTriangles = 0;
};

QuadPairing pairTriangles(const std::vector<float>& xyz, const std::vector<uint32_t>& tris, bool compact)
{
    const std::size_t nt = tris.size() / 3;
    auto key = [](uint32_t a, uint32_t b) { return (uint64_t(a) << 32) | b; };
    std::unordered_map<uint64_t, uint32_t> directed;  // directed edge -> 3 * face + corner
    directed.reserve(3 * nt);
    for (std::size_t f = 0; f < nt; ++f)
        for (uint32_t k = 0; k < 3; ++k)
            directed.emplace(key(tris[3 * f + k], tris[3 * f + (k + 1) % 3]), uint32_t(3 * f + k));
    std::vector<std::array<float, 3>> normal(nt);
    for (std::size_t f = 0; f < nt; ++f) {
        const float* p[3];
        for (int k = 0; k < 3; ++k) p[k] = &xyz[3 * std::size_t(tris[3 * f + std::size_t(k)])];
        const float u[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
        const float v[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
        const float n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
        const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        normal[f] = len > 0 ? std::array<float, 3>{n[0] / len, n[1] / len, n[2] / len} : std::array<float, 3>{0, 0, 0};
    }
    struct Candidate {
        float score;
        uint32_t fk, gj;  // 3 * face + corner of the shared edge's start in each
    };
    std::vector<Candidate> candidates;
    for (std::size_t f = 0; f < nt; ++f)
        for (uint32_t k = 0; k < 3; ++k) {
            const auto it = directed.find(key(tris[3 * f + (k + 1) % 3], tris[3 * f + k]));
            if (it == directed.end() || it->second / 3 <= f) continue;
            const std::size_t g = it->second / 3;
            float score = normal[f][0] * normal[g][0] + normal[f][1] * normal[g][1] + normal[f][2] * normal[g][2];
            if (compact) {  // minus the surface area of the quad's bounding box
                float lo[3], hi[3];
                for (int d = 0; d < 3; ++d) lo[d] = hi[d] = xyz[3 * std::size_t(tris[3 * f]) + std::size_t(d)];
                for (const std::size_t t : {f, g})
                    for (std::size_t q = 0; q < 3; ++q)
                        for (std::size_t d = 0; d < 3; ++d) {
                            const float x = xyz[3 * std::size_t(tris[3 * t + q]) + d];
                            lo[d] = std::min(lo[d], x);
                            hi[d] = std::max(hi[d], x);
                        }
                const float e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
                score = -(e[0] * e[1] + e[1] * e[2] + e[2] * e[0]);
            }
            candidates.push_back({score, uint32_t(3 * f + k), it->second});
        }
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const Candidate& x, const Candidate& y) { return x.score > y.score; });
    std::vector<char> used(nt, 0);
    QuadPairing out;
    for (const Candidate& c : candidates) {
        const uint32_t f = c.fk / 3, k = c.fk % 3, g = c.gj / 3, j = c.gj % 3;
        if (used[f] || used[g]) continue;
        used[f] = used[g] = 1;
        const uint32_t x = tris[3 * f + k], y = tris[3 * f + (k + 1) % 3], z = tris[3 * f + (k + 2) % 3];
        const uint32_t w = tris[3 * g + (j + 2) % 3];
        out.quads.insert(out.quads.end(), {z, x, w, y});  // (z, x, y) = f, (w, y, x) = g
        out.pairedTriangles += 2;
    }
    for (std::size_t f = 0; f < nt; ++f)
        if (!used[f]) out.quads.insert(out.quads.end(), {tris[3 * f], tris[3 * f + 1], tris[3 * f + 2], tris[3 * f + 2]});
    return out;
}

/// The quad scene is the same surface: the robust scenes' depths (benchQuads' trace variants 1
/// and 2) agree ray for ray, on the first camera of every position, untimed.
template <typename Path, typename Trace>
void compareQuadDepths(const Path& path, int px, const Trace& trace)
{
    std::size_t compared = 0, differing = 0;
    double maxRel = 0;
    std::vector<float> depthTri(std::size_t(px) * std::size_t(px)), depthQuad(depthTri.size());
    for (const auto& pair : path) {
        uint64_t h = 0;
        trace(1, pair[0], h, &depthTri);
        trace(2, pair[0], h, &depthQuad);
        for (std::size_t i = 0; i < depthTri.size(); ++i) {
            ++compared;
            const float x = depthTri[i], y = depthQuad[i];
            const double rel = (x < 0) != (y < 0) ? 1.0 : std::fabs(double(x) - double(y)) / std::max(1.0, double(x));
            maxRel = std::max(maxRel, rel);
            differing += rel > 1e-4 ? 1 : 0;
        }
    }
    std::printf("depths, robust triangles vs quads: %zu of %zu rays differ by more than 1e-4 (relative; hit vs miss "
                "counts as 1), max %.2g\n",
                differing, compared, maxRel);
}

void benchQuads(const Args& a, const Subject& s)
{
    std::vector<float> xyz;
    for (const auto v : s.mesh.vertices())
        for (int k = 0; k < 3; ++k) xyz.push_back(s.mesh.point(v)[k]);
    const std::size_t nv = xyz.size() / 3;
    xyz.resize(xyz.size() + 4, 0.f);  // Embree reads up to 16 bytes past the last vertex
    std::vector<uint32_t> tris;
    for (const auto f : s.mesh.faces())
        for (const auto v : s.mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
    const std::size_t nt = tris.size() / 3;

    QuadPairing pairing;
    const Timing pairTime = measure([&] { pairing = pairTriangles(xyz, tris, a.pairing == "compact"); });
    const std::size_t nq = pairing.quads.size() / 4;
    std::printf("\n%zu triangles -> %zu quads: %.2f%% of the triangles paired (pairing %s, %.2f s)\n", nt, nq,
                100.0 * double(pairing.pairedTriangles) / double(nt), a.pairing.c_str(), pairTime.wall);

    RTCDevice device = rtcNewDevice(a.embreeConfig.empty() ? nullptr : a.embreeConfig.c_str());
    if (!device) throw std::runtime_error("rtcNewDevice failed (--embree-config '" + a.embreeConfig + "')");
    if (!a.embreeConfig.empty()) std::printf("Embree device config: %s\n", a.embreeConfig.c_str());
    auto build = [&](bool quads, bool robust) {
        RTCScene scene = rtcNewScene(device);
        rtcSetSceneFlags(scene, RTCSceneFlags((robust ? RTC_SCENE_FLAG_ROBUST : 0) | RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION));
        rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
        RTCGeometry geom = rtcNewGeometry(device, quads ? RTC_GEOMETRY_TYPE_QUAD : RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_MEDIUM);
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, xyz.data(), 0,
                                   3 * sizeof(float), nv);
        if (quads)
            rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4, pairing.quads.data(), 0,
                                       4 * sizeof(uint32_t), nq);
        else
            rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, tris.data(), 0,
                                       3 * sizeof(uint32_t), nt);
        rtcCommitGeometry(geom);
        rtcAttachGeometry(scene, geom);
        rtcReleaseGeometry(geom);
        rtcCommitScene(scene);
        if (rtcGetDeviceError(device) != RTC_ERROR_NONE) throw std::runtime_error("Embree scene build failed");
        return scene;
    };
    // Robust (what RayScene builds) and, for comparison only, Embree's fast mode.
    RTCScene scenes[4] = {nullptr, nullptr, nullptr, nullptr};
    const Timing buildTri = measure([&] { scenes[0] = build(false, true); });
    const Timing buildQuad = measure([&] { scenes[1] = build(true, true); });
    scenes[2] = build(false, false);
    scenes[3] = build(true, false);
    std::printf("BVH build (MEDIUM, robust): triangles %.3f s wall %.3f s CPU, quads %.3f s wall %.3f s CPU\n",
                buildTri.wall, buildTri.cpu, buildQuad.wall, buildQuad.cpu);

    const auto path = flyoverPath(RayScene(s.mesh), s.centerline, a.positions, FlyoverParams{});
    constexpr int P = PACKET, L = LANES;
    const int tilesX = (a.px + P - 1) / P, tilesY = (a.px + P - 1) / P;
    // Variant 0: the packets filled only (the rays' cost, subtracted below); 1: triangles; 2: quads
    // (robust); 3, 4: the same without robust mode.
    auto trace = [&](int variant, const Camera& camera, uint64_t& hitsOut, std::vector<float>* depth) {
        const ViewRays rays(camera, a.px, a.px);  // renderView's rays
        tbb::combinable<uint64_t> hits([] { return uint64_t(0); });
        tbb::parallel_for(tbb::blocked_range2d<int>(0, tilesY, 8, 0, tilesX, 8), [&](const tbb::blocked_range2d<int>& r) {
            const unsigned int csr = _mm_getcsr();
            _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
            _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
            RTCIntersectContext context;
            rtcInitIntersectContext(&context);
            context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
            RTCRayHit16 packet;
            alignas(64) int valid[L];
            uint64_t n = 0;
            for (int ty = r.rows().begin(); ty != r.rows().end(); ++ty)
                for (int tx = r.cols().begin(); tx != r.cols().end(); ++tx) {
                    rays.fill(tx, ty, 0.5f, 0.5f, valid, packet);
                    if (variant > 0) rtcIntersect16(valid, scenes[variant - 1], &context, &packet);
                    for (int i = 0; i < L; ++i) {
                        const bool hit = valid[i] && packet.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
                        n += hit ? 1 : 0;
                        if (depth && valid[i])
                            (*depth)[std::size_t(ty * P + i / P) * std::size_t(a.px) + std::size_t(tx * P + i % P)] =
                                hit ? packet.ray.tfar[i] : -1.f;
                    }
                }
            hits.local() += n;
            _mm_setcsr(csr);
        });
        hitsOut += hits.combine([](uint64_t x, uint64_t y) { return x + y; });
    };
    const double rays = 2.0 * a.px * a.px * double(path.size());
    std::printf("fly-over cameras at %zu positions along the centerline, %d x %d per view: %.1f M rays a run; "
                "the variants alternate view by view (rotating which goes first)\n",
                path.size(), a.px, a.px, rays * 1e-6);
    constexpr int NV = 5;
    const char* names[NV] = {"rays only (packets filled, no traversal)", "triangles, robust  [RayScene today]",
                             "quads, robust", "triangles, not robust (comparison only)",
                             "quads, not robust (comparison only)"};
    std::vector<double> wall[NV], cpu[NV];
    uint64_t hitCount[NV] = {0, 0, 0, 0, 0};
    for (int run = 0; run < a.runs; ++run) {
        double w[NV] = {0, 0, 0, 0, 0}, cp[NV] = {0, 0, 0, 0, 0};
        int view = 0;
        for (const auto& pair : path)
            for (const Camera& camera : pair) {
                for (int o = 0; o < NV; ++o) {
                    const int variant = (o + view) % NV;
                    uint64_t h = 0;
                    const Timing t = measure([&] { trace(variant, camera, h, nullptr); });
                    w[variant] += t.wall;
                    cp[variant] += t.cpu;
                    if (run == 0) hitCount[variant] += h;
                }
                ++view;
            }
        for (int v = 0; v < NV; ++v) {
            wall[v].push_back(w[v]);
            cpu[v].push_back(cp[v]);
        }
    }
    compareQuadDepths(path, a.px, trace);
    std::printf("hits: triangles %llu, quads %llu, not robust %llu / %llu (of %.0f rays)\n",
                static_cast<unsigned long long>(hitCount[1]), static_cast<unsigned long long>(hitCount[2]),
                static_cast<unsigned long long>(hitCount[3]), static_cast<unsigned long long>(hitCount[4]), rays);
    std::printf("  %-44s %9s %9s | %-s\n", "median of runs (traversal = variant - rays only)", "wall s", "CPU s",
                "CPU-normalised traversal Mrays/s");
    const double fillCpu = median(cpu[0]);
    for (int v = 0; v < NV; ++v) {
        const double trav = median(cpu[v]) - fillCpu;
        std::printf("  %-44s %9.3f %9.3f", names[v], median(wall[v]), median(cpu[v]));
        if (v > 0) std::printf(" | %8.1f", rays / (trav / a.threads) * 1e-6);
        std::printf("\n");
    }
    for (const int t : {1, 3}) {
        std::vector<double> ratio;  // per run: triangles' traversal CPU / quads'
        for (int r = 0; r < a.runs; ++r)
            ratio.push_back((cpu[t][std::size_t(r)] - cpu[0][std::size_t(r)]) /
                            (cpu[t + 1][std::size_t(r)] - cpu[0][std::size_t(r)]));
        std::printf("quads' traversal speed-up over triangles, %s (CPU, per run): median %.3f, min %.3f, max %.3f\n",
                    t == 1 ? "robust" : "not robust", median(ratio), *std::min_element(ratio.begin(), ratio.end()),
                    *std::max_element(ratio.begin(), ratio.end()));
    }
    for (RTCScene scene : scenes) rtcReleaseScene(scene);
    rtcReleaseDevice(device);
}

} // namespace

int main(int argc, char** argv)
{
    try {
        const Args a = parseArgs(argc, argv);
        const tbb::global_control threads(tbb::global_control::max_allowed_parallelism, std::size_t(a.threads));
        std::printf("render_bench --mode %s: %d threads, median of %d runs\n", a.mode.c_str(), a.threads, a.runs);
        const Subject s = load(a);
        std::printf("surface: %zu triangles; centerline: %zu points, %.0f mm; %zu truth polyps\n", s.mesh.n_faces(),
                    s.centerline.points.size(), s.centerline.lengthMm(), s.polyps.size());
        if (a.mode == "speed") {
            benchThroughput(a, s);
            benchSceneAndPng(a, s);
            if (!a.study.empty()) benchFirstPair(a);
        } else if (a.mode == "quads") {
            benchQuads(a, s);
        } else if (a.mode == "coverage") {
            benchCoverage(s);
        } else if (a.mode == "marker") {
            benchMarker(a, s);
        } else {
            benchSweep(a, s);
        }
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "render_bench: %s\n", e.what());
        return 1;
    }
}
