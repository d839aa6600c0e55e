// The polyps stage in the study (colon/stage_polyps.cpp): polyps/candidates.json readable by the
// report's strict reader, an OST pair and three CT crops per candidate, camera 0 of the pair
// looking at it, the stage cached by its own parameters and the render parameters its pairs
// take, and `flyover stage polyps` on a study without a surface naming what is missing.
#include "colon/findings.h"
#include "colon/phantom_io.h"
#include "pipeline/artifact_io.h"
#include "pipeline/stage_command.h"
#include "render/camera.h"
#include "tests/pipeline/cli_runner.h"
#include "tests/pipeline/study_fixture.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

class PolypsStage : public StudyTest {};

TEST_F(PolypsStage, CandidatesWithImagesOnThePathAndCached)
{
    RunOptions o = options("polyps");
    o.untilStage = "polyps";
    const nlohmann::json m1 = runPipeline(o);
    const fs::path dir = o.studyDir;
    const std::vector<PolypCandidate> cands = readCandidates((dir / "polyps" / "candidates.json").string());
    // The small phantom's 2.5 mm voxels make a 10 mm polyp four voxels wide: at least half of
    // those are found (the detection's own targets are tested at finer voxels).
    int large = 0;
    for (const PhantomPolyp& p : sPhantom->truth.polyps) large += 2 * p.radiusMm >= 10.0;
    ASSERT_GT(large, 0);
    int foundLarge = 0;
    for (const PhantomPolyp& p : sPhantom->truth.polyps) {
        if (2 * p.radiusMm < 10.0) continue;
        for (const PolypCandidate& c : cands)
            if (distance(c.centroidMm, p.centerMm) <= p.radiusMm + 5.0) {
                ++foundLarge;
                break;
            }
    }
    EXPECT_GE(2 * foundLarge, large) << foundLarge << " of " << large << " polyps of 10 mm or more found";
    ASSERT_FALSE(cands.empty());
    double lastScore = 2;
    for (const PolypCandidate& c : cands) {
        EXPECT_LE(c.score, lastScore) << "best score first";
        lastScore = c.score;
        EXPECT_TRUE(c.huMean.has_value()) << c.id << ": the study has a CT";
        EXPECT_FALSE(c.segment.empty()) << c.id;
        for (const char* kind : {"pair", "axial", "coronal", "sagittal"}) {
            ASSERT_TRUE(c.images.count(kind)) << c.id << " has no " << kind << " image";
            EXPECT_TRUE(fs::is_regular_file(dir / "polyps" / c.images.at(kind))) << c.images.at(kind);
        }
        // Camera 0 of the pair looks at the candidate: it lies ahead, near the view's axis.
        ASSERT_TRUE(c.pose.is_object()) << c.id;
        const auto& cam = c.pose.at("cameras").at(0);
        const Vec3d pos{cam.at("position_mm")[0], cam.at("position_mm")[1], cam.at("position_mm")[2]};
        const Vec3d fwd{cam.at("forward")[0], cam.at("forward")[1], cam.at("forward")[2]};
        const Vec3d to = c.centroidMm - pos;
        EXPECT_GT(dot(to, fwd) / length(to), std::cos(25.0 * 3.14159265358979 / 180.0))
            << c.id << ": camera 0 does not look at the candidate";
    }
    const RgbImage pair = readPng((dir / "polyps" / cands[0].images.at("pair")).string());
    EXPECT_EQ(pair.width, 2 * o.params.render.widthPx + 4);

    // Cached: a re-run reuses it; its own parameter and a render parameter of its pairs
    // recompute it; a render parameter it does not take does not.
    auto computed = [&](const RunOptions& run) { return computedStages(runPipeline(run)).at("polyps"); };
    EXPECT_FALSE(computed(o));
    RunOptions other = o;
    other.params.render.videoFps = 12;
    EXPECT_FALSE(computed(other)) << "render.video_fps is not a parameter of the polyps' pairs";
    other.params.polyps.minSizeMm = 8;
    EXPECT_TRUE(computed(other));
    other.params.render.fovDeg = 80;
    EXPECT_TRUE(computed(other));
    EXPECT_LE(readCandidates((dir / "polyps" / "candidates.json").string()).size(), cands.size())
        << "a larger polyps.min_size_mm keeps no more candidates";
}

TEST_F(PolypsStage, StageCommandWithoutASurfaceNamesTheMissingStage)
{
    RunOptions o = options("polyps-no-mesh");
    o.untilStage = "centerline";
    runPipeline(o);
    const CliResult r = runFlyover("-q stage polyps --study " + o.studyDir);
    EXPECT_EQ(r.exitCode, EXIT_NOT_READY) << r.err;
    EXPECT_NE(r.err.find("mesh"), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "one line: " << r.err;
    EXPECT_FALSE(fs::exists(fs::path(o.studyDir) / "polyps")) << "nothing written";
}

} // namespace
