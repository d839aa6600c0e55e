// Studies that take the lumen from an external mask (`flyover run --mask FILE [--label N]`):
// alone (the real TotalSegmentator colon label, no CT: ingest is skipped), or beside a CT (the
// phantom's true lumen mask, matched to the CT's grid). The mask's content is part of the
// segment stage's key. Also: the centerline exports (.mrk.json, .vtk) and the --rectum-mm and
// --step-mm shortcuts.
#include "tests/pipeline/cli_runner.h"
#include "pipeline/artifact_io.h"
#include "colon/export.h"
#include "tests/pipeline/study_fixture.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover::test {
namespace {

std::string realFixture(const std::string& name)
{
    return std::string(FLYOVER_SOURCE_DIR) + "/data/fixtures/real/" + name;
}

int runCli(const std::string& args, std::string* err = nullptr)
{
    const CliResult r = runFlyover(args);
    if (err) *err = r.err;
    return r.exitCode;
}

class MaskStudy : public StudyTest {
protected:
    /// A mask-only study of the real colon label (label 20), small frames.
    RunOptions maskOptions(const std::string& study, const std::string& maskPath) const
    {
        RunOptions o = options(study);
        o.ctPath.clear();
        o.maskPath = maskPath;
        o.params.segment.maskLabel = 20;
        return o;
    }
};

TEST_F(MaskStudy, MaskAloneRunsEveryStageButIngestAndItsContentIsInTheKey)
{
    // The mask is copied into the study's parent so that its content can change under the same
    // name.
    const std::string mask = (sRoot / "colon_label.nii.gz").string();
    fs::copy_file(realFixture("example_seg.nii.gz"), mask, fs::copy_options::overwrite_existing);
    RunOptions o = maskOptions("maskonly", mask);
    json m = runPipeline(o);
    EXPECT_EQ(computedStages(m), withRenderSteps({{"segment", true}, {"centerline", true}, {"mesh", true}}, true));
    EXPECT_TRUE(m["input"].is_null());
    EXPECT_EQ(m["mask"], fs::absolute(mask).string());
    json segment;
    for (const auto& s : m["stages"])
        if (s["stage"] == "segment") segment = s;
    ASSERT_FALSE(segment.is_null());
    EXPECT_EQ(segment["report"]["source"], "mask");
    EXPECT_EQ(segment["report"]["mask"]["label"], 20);
    EXPECT_EQ(segment["report"]["mask"]["label_voxels"], 12993);  // the README's count for label 20
    EXPECT_TRUE(segment["inputs"].contains("mask"));
    EXPECT_FALSE(segment["inputs"].contains("ct.vdb"));
    EXPECT_FALSE(fs::exists(fs::path(o.studyDir) / "ct.vdb"));
    // Through to a mesh and the overview images.
    EXPECT_GT(fs::file_size(fs::path(o.studyDir) / "surface.ply"), 10000u);
    EXPECT_GT(fs::file_size(fs::path(o.studyDir) / "overview.png"), 1000u);
    EXPECT_TRUE(fs::exists(fs::path(o.studyDir) / "overviews" / "anterior.png"));

    // One ordered path over both pieces of the broken label, the bridge marked.
    const Centerline cl = centerlineFromJson(readJson(o.studyDir + "/centerline.json"), "centerline.json");
    int bridged = 0;
    for (const auto& p : cl.points) bridged += p.bridged;
    EXPECT_GT(bridged, 10);
    EXPECT_GT(cl.lengthMm(), 150.0);

    // Status: ingest unused, the rest fresh; a re-run computes nothing.
    // (Named fields: a braced list put its last value into StatusOptions::inspect, not into
    // paramsGiven, so the second call below compared with the last run's parameters.)
    auto statusOf = [&](const PipelineParams* given) {
        StatusOptions so;
        so.studyDir = o.studyDir;
        if (given) {
            so.params = *given;
            so.paramsGiven = true;
        }
        return studyStatus(so);
    };
    for (const StageStatus& st : statusOf(nullptr))
        EXPECT_EQ(st.state, st.stage == "ingest" ? "unused" : "fresh") << st.stage << ": " << st.reason;
    m = runPipeline(o);
    for (const auto& [stage, computed] : computedStages(m)) EXPECT_FALSE(computed) << stage;

    // Another mask under the same name (the binary colon mask, label 0 = every non-zero voxel):
    // segment and everything after it recompute, and status says why before the run.
    fs::copy_file(realFixture("example_seg_fast_colon.nii.gz"), mask, fs::copy_options::overwrite_existing);
    o.params.segment.maskLabel = 0;
    bool sawMaskChange = false;
    PipelineParams p = o.params;
    for (const StageStatus& st : statusOf(&p))
        if (st.stage == "segment") sawMaskChange = st.state == "stale";
    EXPECT_TRUE(sawMaskChange);
    m = runPipeline(o);
    EXPECT_EQ(computedStages(m), withRenderSteps({{"segment", true}, {"centerline", true}, {"mesh", true}}, true));
}

TEST_F(MaskStudy, CtWithTheTrueMaskMatchesTheCtSegmentation)
{
    // The phantom's true lumen mask beside its CT: segment reads both, and the lumen it gives is
    // within a few percent of the one segmented from the CT's air.
    const std::string mask = (sRoot / "truth_mask.nii.gz").string();
    PhantomParams pp;
    pp.size = PhantomSize::Small;
    pp.seed = STUDY_SEED;
    writePhantom(*sPhantom, pp, (sRoot / "ct_again.nii.gz").string(), (sRoot / "truth_again.json").string(), mask);

    RunOptions fromCt = options("ctonly");
    fromCt.untilStage = "segment";
    RunOptions withMask = fromCt;
    withMask.studyDir = studyDir("ctmask");
    withMask.maskPath = mask;
    auto segmentOf = [](const json& manifest) {
        for (const auto& s : manifest["stages"])
            if (s["stage"] == "segment") return s;
        return json();
    };
    const json a = segmentOf(runPipeline(fromCt)), b = segmentOf(runPipeline(withMask));
    EXPECT_EQ(b["report"]["source"], "mask");
    EXPECT_TRUE(b["inputs"].contains("ct.vdb") && b["inputs"].contains("mask"));
    const double va = a["report"]["lumen_volume_ml"].get<double>(), vb = b["report"]["lumen_volume_ml"].get<double>();
    EXPECT_NEAR(vb, va, 0.05 * va) << "lumen from the CT " << va << " mL, from the true mask " << vb << " mL";
}

TEST_F(MaskStudy, CenterlineExportsForSlicerAndVtkCarryEveryPoint)
{
    RunOptions o = maskOptions("export", realFixture("example_seg.nii.gz"));
    o.untilStage = "centerline";
    runPipeline(o);
    const Centerline cl = centerlineFromJson(readJson(o.studyDir + "/centerline.json"), "centerline.json");
    ASSERT_GT(cl.points.size(), 100u);

    const std::string mrk = (sRoot / "cl.mrk.json").string();
    exportCenterline(o.studyDir, mrk);
    const json j = readJson(mrk);
    ASSERT_EQ(j["markups"].size(), 1u);
    const json& curve = j["markups"][0];
    EXPECT_EQ(curve["type"], "Curve");
    EXPECT_EQ(curve["coordinateSystem"], "LPS");
    ASSERT_EQ(curve["controlPoints"].size(), cl.points.size());
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        const json& cp = curve["controlPoints"][i];
        EXPECT_DOUBLE_EQ(cp["position"][0].get<double>(), cl.points[i].positionMm.x) << "point " << i;
        EXPECT_DOUBLE_EQ(cp["position"][2].get<double>(), cl.points[i].positionMm.z) << "point " << i;
        EXPECT_EQ(cp["description"] == "bridged", cl.points[i].bridged) << "point " << i;
    }

    const std::string vtk = (sRoot / "cl.vtk").string();
    exportCenterline(o.studyDir, vtk);
    std::ifstream in(vtk);
    std::string line, word, type;
    std::getline(in, line);
    EXPECT_EQ(line, "# vtk DataFile Version 3.0");
    std::getline(in, line);
    EXPECT_NE(line.find("SPACE=LPS"), std::string::npos) << line;
    std::getline(in, line);
    std::getline(in, line);
    EXPECT_EQ(line, "DATASET POLYDATA");
    std::size_t n = 0;
    in >> word >> n >> type;
    EXPECT_EQ(word, "POINTS");
    EXPECT_EQ(n, cl.points.size());
    double x = 0, y = 0, z = 0;
    in >> x >> y >> z;
    EXPECT_NEAR(x, cl.points[0].positionMm.x, 1e-6);
    EXPECT_NEAR(y, cl.points[0].positionMm.y, 1e-6);
    EXPECT_NEAR(z, cl.points[0].positionMm.z, 1e-6);

    EXPECT_THROW(exportCenterline(o.studyDir, (sRoot / "cl.txt").string()), InputError);
    EXPECT_THROW(exportCenterline(studyDir("nostudy"), mrk), InputError);
}

TEST_F(MaskStudy, CliMaskRectumAndStepOptions)
{
    const std::string study = studyDir("cli");
    const std::string base = "--quiet run --mask " + realFixture("example_seg.nii.gz") + " --label 20 --study " + study +
                             " --until centerline";
    ASSERT_EQ(runCli(base), 0);
    const Centerline first = centerlineFromJson(readJson(study + "/centerline.json"), "centerline.json");
    ASSERT_GT(first.points.size(), 10u);
    // Start at the other end, with a 2 mm step.
    const Vec3d end = first.points.back().positionMm;
    std::ostringstream at;
    at.precision(10);
    at << end.x << "," << end.y << "," << end.z;
    ASSERT_EQ(runCli(base + " --rectum-mm " + at.str() + " --step-mm 2"), 0);
    const Centerline second = centerlineFromJson(readJson(study + "/centerline.json"), "centerline.json");
    EXPECT_DOUBLE_EQ(second.stepMm, 2.0);
    // The same curve from either end: this partial colon's lumen is in
    // two pieces and has cycles (the first contact search cut three links on it, contacts v2
    // none: none has a long way round); the hinted piece
    // used to be traced from the hint to its farthest voxel, another way round a cycle than the
    // first path (up to 23 mm off it, 7-8% longer). The standard: 5 mm, 5%.
    EXPECT_LT(distance(second.points.front().positionMm, end), 5.0);
    EXPECT_LT(distance(second.points.back().positionMm, first.points.front().positionMm), 5.0);
    EXPECT_NEAR(second.lengthMm(), first.lengthMm(), 0.05 * first.lengthMm());
    // Every point of the second path lies within 5 mm of the first path.
    double worst = 0;
    for (const CenterlinePoint& p : second.points) {
        double best = 1e300;
        for (const CenterlinePoint& q : first.points) best = std::min(best, distance(p.positionMm, q.positionMm));
        worst = std::max(worst, best);
    }
    EXPECT_LT(worst, 5.0) << "the path from the other end leaves the first path";

    // Command-line mistakes: one line, exit code 2 (usage) or 1 (the file).
    std::string err;
    EXPECT_EQ(runCli("run --study " + study, &err), 2) << err;
    EXPECT_NE(err.find("give a CT scan, --mask FILE, or both"), std::string::npos) << err;
    EXPECT_EQ(runCli("run " + ctPath() + " --label 3 --study " + study, &err), 2) << err;
    EXPECT_NE(err.find("--label requires --mask"), std::string::npos) << err;
    EXPECT_EQ(runCli("run --mask " + study + "/nothing.nii.gz --study " + study, &err), 1) << err;
    EXPECT_NE(err.find("nothing.nii.gz: --mask: no such file"), std::string::npos) << err;
    EXPECT_EQ(runCli("run --mask " + realFixture("example_seg.nii.gz") + " --study " + study + " --step-mm 0", &err), 2)
        << err;
    EXPECT_EQ(runCli("run --mask " + realFixture("example_seg.nii.gz") + " --study " + study + " --rectum-mm 1,2", &err), 2)
        << err;
    EXPECT_NE(err.find("rectum_mm"), std::string::npos) << err;
}

} // namespace
} // namespace flyover::test
