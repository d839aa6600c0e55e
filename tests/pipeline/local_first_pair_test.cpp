// The first fly-over pair from a local surface (issue 15, colon/local_first_pair.h): shown
// only when certified, and then the very pixels of the whole surface's scene.

#include "colon/local_first_pair.h"
#include "pipeline/run_log.h"
#include "pipeline/study.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "surface/lumen_surface.h"
#include "volume/image_io.h"
#include "volume/vec3.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <fstream>
#include <map>
#include <filesystem>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

struct Tube {
    Vec3d a, b;
    double radiusMm;
};

/// A narrow-band level set (negative inside) of the union of `tubes` (capsules), 1 mm voxels.
openvdb::FloatGrid::Ptr tubesLevelSet(const std::vector<Tube>& tubes)
{
    constexpr double VOXEL = 1.0, BAND = 3.0;
    auto grid = openvdb::FloatGrid::create(float(BAND * VOXEL));
    grid->setTransform(openvdb::math::Transform::createLinearTransform(VOXEL));
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    auto acc = grid->getAccessor();
    for (const Tube& t : tubes) {
        const Vec3d lo{std::min(t.a.x, t.b.x) - t.radiusMm - 4, std::min(t.a.y, t.b.y) - t.radiusMm - 4,
                       std::min(t.a.z, t.b.z) - t.radiusMm - 4};
        const Vec3d hi{std::max(t.a.x, t.b.x) + t.radiusMm + 4, std::max(t.a.y, t.b.y) + t.radiusMm + 4,
                       std::max(t.a.z, t.b.z) + t.radiusMm + 4};
        for (int k = int(std::floor(lo.z)); k <= int(std::ceil(hi.z)); ++k)
            for (int j = int(std::floor(lo.y)); j <= int(std::ceil(hi.y)); ++j)
                for (int i = int(std::floor(lo.x)); i <= int(std::ceil(hi.x)); ++i) {
                    const Vec3d p{double(i), double(j), double(k)};
                    double d = 1e9;
                    for (const Tube& u : tubes) d = std::min(d, distanceToSegment(p, u.a, u.b) - u.radiusMm);
                    if (std::fabs(d) < BAND * VOXEL) acc.setValue(openvdb::Coord(i, j, k), float(d));
                }
    }
    return grid;
}

/// The path along the first tube, from its lower end, every mm.
Centerline tubeCenterline(const Tube& t)
{
    Centerline cl;
    const double length = distance(t.a, t.b);
    for (int s = 0; s <= int(length); ++s) {
        CenterlinePoint p;
        p.positionMm = t.a + (t.b - t.a) * (double(s) / length);
        p.radiusMm = t.radiusMm;
        cl.points.push_back(p);
    }
    cl.stepMm = 1.0;
    computeTangentsAndNormals(cl);
    return cl;
}

RenderOptions frameOptions()
{
    RenderOptions ro;
    ro.widthPx = ro.heightPx = 128;
    ro.ost = true;
    return ro;
}

/// The first pair as the frames step renders it from the whole surface.
RgbImage wholeSurfacePair(const openvdb::FloatGrid& sdf, const Centerline& cl, const FlyoverParams& fp,
                          const RenderOptions& ro, double& frameRadius)
{
    const TriMesh mesh = makeLumenSurface(sdf, MeshParams{});
    const RayScene scene(mesh);
    frameRadius = flyoverFrameRadiusAt(scene, cl, fp, 0);
    const auto cams = flyoverCameras(cl.points[0], fp, frameRadius);
    RgbImage pair;
    renderPair(scene, cams[0], cams[1], ro, pair);
    return pair;
}

const Tube COLON{{0, 0, 0}, {0, 0, 400}, 12.0};
/// A pouch off the tube near its end, as a haustrum: the frame radius measured on the surface
/// then exceeds the tube's radius, the near planes reach out of the lumen and some rays pass
/// beside it (as on the phantoms and real colons).
const Tube POUCH{{0, 16, 12}, {0, 16, 12}, 10.0};

/// The long tube with its pouch as a mask (NIfTI, 1 mm voxels) in `root`; returns its path.
std::string writeTubeMask(const fs::path& root)
{
    Image3<uint8_t> mask;
    mask.geometry.size = {48, 48, 440};
    mask.geometry.originMm = {-24, -24, -20};
    mask.voxels.assign(std::size_t(mask.geometry.voxelCount()), 0);
    for (int64_t k = 0; k < mask.geometry.size[2]; ++k)
        for (int64_t j = 0; j < mask.geometry.size[1]; ++j)
            for (int64_t i = 0; i < mask.geometry.size[0]; ++i) {
                const Vec3d p = mask.geometry.worldFromIndex(Vec3d{double(i), double(j), double(k)});
                if (distanceToSegment(p, COLON.a, COLON.b) <= COLON.radiusMm ||
                    distanceToSegment(p, POUCH.a, POUCH.b) <= POUCH.radiusMm)
                    mask.at(i, j, k) = 1;
            }
    const std::string maskPath = (root / "tube.nii.gz").string();
    writeImage(mask, maskPath);
    return maskPath;
}

} // namespace

TEST(LocalFirstPair, ACertifiedPairHasTheWholeSurfacesPixels)
{
    const auto sdf = tubesLevelSet({COLON, POUCH});
    const Centerline cl = tubeCenterline(COLON);
    const FlyoverParams fp;
    const RenderOptions ro = frameOptions();
    const LocalFirstPair local = localFirstPair(*sdf, cl, 0, MeshParams{}, fp, ro);
    ASSERT_TRUE(local.certified) << local.reason;
    EXPECT_LT(local.clipLeafFraction, 0.35);
    double radius = 0;
    const RgbImage whole = wholeSurfacePair(*sdf, cl, fp, ro, radius);
    EXPECT_EQ(local.frameRadiusMm, radius) << "the frame radius from the local surface is not the whole one's";
    EXPECT_EQ(differingPixels(local.pair, whole), 0u) << "a certified local pair differs from the whole scene's";
    EXPECT_GT(local.localTriangles, 0u);
}

// The fan rays' box check: the same R as without it; `within` only when every ray stays inside.
TEST(LocalFirstPair, FanRaysAreCheckedAgainstTheBox)
{
    const auto sdf = tubesLevelSet({COLON, POUCH});
    const Centerline cl = tubeCenterline(COLON);
    const RayScene scene(makeLumenSurface(*sdf, MeshParams{}));
    const FlyoverParams fp;
    const double plain = flyoverFrameRadiusAt(scene, cl, fp, 0);
    bool within = false;
    const BoxMm large{Vec3d{-100, -100, -100}, Vec3d{100, 100, 200}};
    EXPECT_EQ(flyoverFrameRadiusAt(scene, cl, fp, 0, {}, large, within), plain);
    EXPECT_TRUE(within);
    // The pouch reaches y = 26 mm: a box to y = 20 mm cuts the rays that find it.
    const BoxMm cut{Vec3d{-100, -100, -100}, Vec3d{100, 20, 200}};
    EXPECT_EQ(flyoverFrameRadiusAt(scene, cl, fp, 0, {}, cut, within), plain);
    EXPECT_FALSE(within) << "fan rays that end beyond the box were taken as inside";
}

// A second loop behind the first, outside the box the pair is made in: rays that pass the first
// tube's end meet it. The local surface does not hold it, so its pair differs from the whole
// one's, and the check of the rays that met nothing refuses it.
TEST(LocalFirstPair, ALoopBehindTheBoxIsNotShown)
{
    const Tube behind{{-130, 0, -150}, {-130, 0, 400}, 14.0};
    const auto sdf = tubesLevelSet({COLON, POUCH, behind});
    const Centerline cl = tubeCenterline(COLON);
    const FlyoverParams fp;
    const RenderOptions ro = frameOptions();
    const LocalFirstPair local = localFirstPair(*sdf, cl, 0, MeshParams{}, fp, ro);
    EXPECT_FALSE(local.certified) << "a pair missing a loop in view was certified";
    EXPECT_NE(local.reason.find("pass the level set outside"), std::string::npos) << local.reason;
    EXPECT_GT(local.uncertainPixels, 0u);
    double radius = 0;
    const RgbImage whole = wholeSurfacePair(*sdf, cl, fp, ro, radius);
    EXPECT_GT(differingPixels(local.pair, whole), 0u)
        << "the loop behind did not show in the whole scene's pair: the test sees nothing";
}

TEST(LocalFirstPair, SmallLumensSupersampledFramesAndDecimatedMeshesAreLeftToTheFramesStep)
{
    const Tube shortTube{{0, 0, 0}, {0, 0, 80}, 12.0};
    const auto small = tubesLevelSet({shortTube});
    const LocalFirstPair whole = localFirstPair(*small, tubeCenterline(shortTube), 0, MeshParams{}, {}, frameOptions());
    EXPECT_FALSE(whole.certified);
    EXPECT_NE(whole.reason.find("holds most of the surface"), std::string::npos) << whole.reason;
    EXPECT_EQ(whole.localTriangles, 0u) << "meshed although the box holds the whole lumen";

    RenderOptions ss = frameOptions();
    ss.supersample = 2;
    EXPECT_FALSE(localFirstPairApplies(MeshParams{}, ss));
    MeshParams decimated;
    decimated.decimateFraction = 0.5;
    EXPECT_FALSE(localFirstPairApplies(decimated, frameOptions()));
    EXPECT_TRUE(localFirstPairApplies(MeshParams{}, frameOptions()));
}

// Through the pipeline, from a mask of the same long tube: the first pair is announced before
// the segment stage ends (the mesh is not waited for), the frames step confirms it on the whole
// scene, and every artifact is the one a run without the local pair makes.
TEST(LocalFirstPair, ThePipelineAnnouncesItBeforeTheMeshAndChangesNoArtifact)
{
    const fs::path root = fs::temp_directory_path() / ("flyover-local-pair-" + std::to_string(::getpid()));
    fs::remove_all(root);
    fs::create_directories(root);
    const std::string maskPath = writeTubeMask(root);

    auto run = [&](const std::string& name, std::string* log) {
        RunOptions o;
        o.maskPath = maskPath;
        o.studyDir = (root / name).string();
        o.untilStage = "frames";
        o.params.render.widthPx = o.params.render.heightPx = 128;
        o.params.render.frameStepMm = 150;
        std::ostringstream out;
        RunLog json(RunLog::Mode::Json, out);
        if (log) o.log = &json;
        const nlohmann::json manifest = runPipeline(o);
        if (log) *log = out.str();
        return manifest;
    };
    std::string log;
    const nlohmann::json withLocal = run("local", &log);
    ::setenv("FLYOVER_TEST_NO_LOCAL_FIRST_PAIR", "1", 1);
    nlohmann::json without;
    try {
        without = run("framesstep", nullptr);
    } catch (...) {
        ::unsetenv("FLYOVER_TEST_NO_LOCAL_FIRST_PAIR");
        throw;
    }
    ::unsetenv("FLYOVER_TEST_NO_LOCAL_FIRST_PAIR");

    auto report = [](const nlohmann::json& manifest, const std::string& stage) {
        for (const auto& s : manifest.at("stages"))
            if (s.at("stage") == stage) return s.at("report");
        ADD_FAILURE() << "no " << stage << " stage";
        return nlohmann::json();
    };
    const nlohmann::json frames = report(withLocal, "frames");
    ASSERT_TRUE(frames.at("local_first_pair").at("certified").get<bool>()) << frames.at("local_first_pair");
    EXPECT_EQ(frames.at("first_pair_scene").at("scene"), "local surface round the first cameras (segment stage)");
    EXPECT_EQ(frames.at("first_pair_check").at("differing_pixels").get<std::size_t>(), 0u);
    EXPECT_FALSE(frames.at("first_pair_check").at("replaced").get<bool>());
    EXPECT_TRUE(report(without, "frames").at("local_first_pair").is_null());
    for (const auto& s : withLocal.at("stages")) {
        bool found = false;
        for (const auto& t : without.at("stages"))
            if (t.at("stage") == s.at("stage")) {
                found = true;
                EXPECT_EQ(s.at("outputs"), t.at("outputs")) << "stage " << s.at("stage");
            }
        EXPECT_TRUE(found) << s.at("stage");
    }
    // The event comes before the segment stage's end, and once.
    const auto firstPair = log.find("\"event\":\"first_pair\"");
    ASSERT_NE(firstPair, std::string::npos) << log;
    EXPECT_EQ(log.find("\"event\":\"first_pair\"", firstPair + 1), std::string::npos) << "announced twice";
    std::size_t segmentFinished = std::string::npos;
    for (std::size_t at = log.find("stage_finished"); at != std::string::npos; at = log.find("stage_finished", at + 1)) {
        const std::size_t lineStart = log.rfind('\n', at) == std::string::npos ? 0 : log.rfind('\n', at);
        const std::size_t lineEnd = log.find('\n', at);
        if (log.substr(lineStart, lineEnd - lineStart).find("\"stage\":\"segment\"") != std::string::npos)
            segmentFinished = at;
    }
    ASSERT_NE(segmentFinished, std::string::npos) << log;
    EXPECT_LT(firstPair, segmentFinished) << "the first pair came after the segment stage";
    fs::remove_all(root);
}

// kill -9 at the local first pair's moments leaves nothing a later run trusts: the pair is in
// frames/ alone and unrecorded, the segment stage's files are renamed but not recorded.
TEST(LocalFirstPair, RunsKilledAroundItLeaveNothingThatLies)
{
    const fs::path root = fs::temp_directory_path() / ("flyover-local-pair-kill-" + std::to_string(::getpid()));
    fs::remove_all(root);
    fs::create_directories(root);
    const std::string flyover = FLYOVER_BIN, mask = writeTubeMask(root);
    const std::string common = " --mask " + mask + " --until frames --set render.width_px=128 --set "
                               "render.height_px=128 --set render.frame_step_mm=150";
    auto digests = [](const std::string& study) {
        std::ifstream in(study + "/manifest.json");
        const nlohmann::json m = nlohmann::json::parse(in);
        std::map<std::string, nlohmann::json> out;
        for (const auto& s : m.at("stages")) out[s.at("stage").get<std::string>()] = s.at("outputs");
        return out;
    };
    const std::string ref = (root / "ref").string();
    ASSERT_EQ(std::system((flyover + " -q run --study " + ref + common).c_str()), 0);
    for (const char* point : {"frames:first-pair", "writebehind:segment:renamed", "stage:segment:committed"}) {
        const std::string s = (root / (std::string("crash-") + point)).string();
        const int killed = std::system(("FLYOVER_CRASH_AT=" + std::string(point) + " " + flyover + " -q run --study " +
                                        s + common + " 2>/dev/null").c_str());
        EXPECT_NE(killed, 0) << "the run did not reach crash point " << point;
        if (std::string(point) == "frames:first-pair") {
            EXPECT_TRUE(fs::is_regular_file(s + "/frames/pair_0000.png")) << "the first pair was not out at " << point;
        }
        ASSERT_EQ(std::system((flyover + " -q run --study " + s + common).c_str()), 0) << point;
        EXPECT_EQ(digests(s), digests(ref)) << "after a crash at " << point;
        for (const auto& e : fs::recursive_directory_iterator(s))
            EXPECT_NE(e.path().filename().string().rfind(".tmp-", 0), 0u) << point << ": " << e.path();
    }
    fs::remove_all(root);
}
