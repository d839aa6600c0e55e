// Loop-local OST on phantoms whose loops press together (every contact the phantom has, the
// extra sigmoid and transverse loops; even seeds with the rectum the widest lumen), from the
// CT and from the mask, several seeds: of the
// wall pixels of the fly-over views, the share that belongs to a part of the colon more than
// 80 mm away along it. Which wall belongs where is decided by the phantom's true centerline
// (bench/foreign_walls.h: the true centerline point a wall's inward normal runs through), not
// by the render's own owners; the view's place is the true arc nearest its path point.
#include "bench/foreign_walls.h"
#include "colon/phantom.h"
#include "colon/phantom_io.h"
#include "pipeline/artifact_io.h"
#include "colon/colon_study.h"
#include "render/loop_ownership.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>

namespace fs = std::filesystem;
using namespace flyover;
using nlohmann::json;

namespace {

Vec3d vec(const json& a) { return {a.at(0).get<double>(), a.at(1).get<double>(), a.at(2).get<double>()}; }


/// The truth's centerline as a Centerline (1 mm steps, as the truth is sampled).
Centerline truthCenterline(const Phantom& ph)
{
    Centerline c;
    c.stepMm = 1.0;
    for (std::size_t i = 0; i < ph.truth.centerlineMm.size(); ++i) {
        CenterlinePoint p;
        p.positionMm = ph.truth.centerlineMm[i];
        p.radiusMm = ph.truth.radiusMm[i];
        c.points.push_back(p);
    }
    return c;
}

struct Shares {
    double thesis = 0, local = 0, reported = 0, withReview = 0;
};

Shares runPacked(uint64_t seed, bool fromMask)
{
    const fs::path dir = fs::temp_directory_path() /
                         ("flyover-looplocal-" + std::to_string(seed) + (fromMask ? "m-" : "c-") + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    PhantomParams pp;
    pp.size = PhantomSize::Small;
    pp.seed = seed;
    pp.touching = PHANTOM_MAX_CONTACTS;
    pp.redundant = true;
    pp.wideRectum = seed % 2 == 0;  // and with the rectum the widest lumen
    const Phantom ph = makePhantom(pp);
    writePhantom(ph, pp, (dir / "ct.nii.gz").string(), (dir / "truth.json").string(),
                 fromMask ? (dir / "mask.nii.gz").string() : "");
    RunOptions run;
    if (fromMask) run.maskPath = (dir / "mask.nii.gz").string();
    else run.ctPath = (dir / "ct.nii.gz").string();
    run.studyDir = (dir / "study").string();
    run.untilStage = "render";
    run.params.render.widthPx = run.params.render.heightPx = 96;
    run.params.render.frameStepMm = 20;
    run.params.render.coveragePx = 48;
    run.params.render.video = false;
    run.params.render.flythroughFrames = false;
    runPipeline(run);

    const std::string study = run.studyDir;
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    EXPECT_TRUE(readPlainPly(study + "/surface.ply", xyz, tris));
    const RayScene scene(std::move(xyz), std::move(tris));
    const Centerline cl = centerlineFromJson(readJson(study + "/centerline.json"), "centerline.json");
    const Centerline truth = truthCenterline(ph);
    const std::vector<float> owners = triangleOwners(scene, cl).arcMm;
    const std::vector<float> reference = bench::normalLineOwners(scene, truth);
    const CenterlineLocator onTruth(truth);
    const json poses = readJson(study + "/frames/poses.json");
    bench::ForeignPixels thesis, local;
    double reported = 0;
    for (const json& f : poses.at("frames")) {
        const double arc = f.at("arc_mm").get<double>();
        const double truthArc = double(onTruth.nearest(vec(f.at("centerline_point_mm"))));
        for (const json& c : f.at("cameras")) {
            const Camera cam = bench::cameraOfJson(c);
            const auto a = bench::foreignPixels(scene, cam, 96, LoopWindow{}, reference, truthArc, 80.0);
            const auto b = bench::foreignPixels(scene, cam, 96, LoopWindow{&owners, arc, 80.0}, reference, truthArc, 80.0);
            thesis.wall += a.wall;
            thesis.foreign += a.foreign;
            local.wall += b.wall;
            local.foreign += b.foreign;
        }
        EXPECT_TRUE(f.contains("foreign_wall_share")) << "frames/poses.json names no foreign wall share";
        reported = std::max(reported, f.value("foreign_wall_share", 0.0));
    }
    const json coverage = readJson(study + "/coverage/coverage.json");
    Shares s{thesis.share(), local.share(), reported,
             coverage.at("flyover_with_review").at("fraction").get<double>()};
    std::printf("[ measure  ] seed %llu from the %s: foreign wall share thesis OST %.2f%%, loop-local %.2f%%; "
                "largest reported per pose %.1f%%; coverage with review %.2f%%\n",
                (unsigned long long)seed, fromMask ? "mask" : "CT", 100 * s.thesis, 100 * s.local, 100 * s.reported,
                100 * s.withReview);
    fs::remove_all(dir);
    return s;
}

} // namespace

TEST(LoopLocalPhantom, PackedLoopsFillNoViewFromTheMask)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2}) {
        const Shares s = runPacked(seed, true);
        EXPECT_LE(s.local, 0.01) << "seed " << seed << ": share of wall pixels from loops > 80 mm away";
        EXPECT_LE(s.local, 0.25 * s.thesis) << "seed " << seed << ": loop-local should pass most foreign walls";
        EXPECT_GE(s.withReview, 0.995) << "seed " << seed << ": coverage with review";
    }
}

TEST(LoopLocalPhantom, PackedLoopsFillNoViewFromTheCt)
{
    openvdb::initialize();
    const Shares s = runPacked(3, false);
    EXPECT_LE(s.local, 0.01) << "share of wall pixels from loops > 80 mm away";
    EXPECT_LE(s.local, 0.25 * s.thesis) << "loop-local should pass most foreign walls";
    EXPECT_GE(s.withReview, 0.995) << "coverage with review";
}
