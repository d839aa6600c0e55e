// `flyover inspect` end to end on a small uint16 test part (96^3, 0.5 mm): voids.csv and
// voids.json, the cache (an unchanged re-run recomputes nothing, a render parameter only its
// step), every listed void visible in an OST overview and hidden in the normal render, and bad
// input refused in one line with exit 1 (2 for an unknown parameter).
#include "tests/pipeline/cli_runner.h"
#include "tests/inspect/part_fixture.h"
#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {
namespace {

const char* const HEADER = "id,kind,volume_mm3,equivalent_diameter_mm,max_extent_mm,sphericity,centroid_x_mm,"
                           "centroid_y_mm,centroid_z_mm,distance_to_surface_mm";
/// Small and quick renders for the tests.
const char* const QUICK = "--set render.overview_px=128 --set render.supersample=1 --set render.video_px=96 "
                          "--set render.turntable_frames=4";

bool haveFfmpeg() { return std::system("command -v ffmpeg >/dev/null 2>&1") == 0; }

std::map<std::string, bool> computed(const json& manifest)
{
    std::map<std::string, bool> out;
    for (const auto& s : manifest.at("stages")) out[s.at("stage").get<std::string>()] = s.at("computed").get<bool>();
    return out;
}

std::vector<std::vector<std::string>> readCsv(const std::string& path, std::string& header)
{
    std::ifstream in(path);
    std::getline(in, header);
    std::vector<std::vector<std::string>> rows;
    for (std::string line; std::getline(in, line);) {
        std::vector<std::string> cells;
        std::stringstream ss(line);
        for (std::string cell; std::getline(ss, cell, ',');) cells.push_back(cell);
        rows.push_back(cells);
    }
    return rows;
}

struct InspectTest : ::testing::Test {
    static void SetUpTestSuite()
    {
        root = new fs::path(fs::temp_directory_path() / ("flyover-inspect-" + std::to_string(::getpid())));
        fs::remove_all(*root);
        fs::create_directories(*root);
        part = new test::TestPart(test::makeTestPart(96));
        test::writeNrrdU16((*root / "part.nrrd").string(), part->geometry, part->grey);
    }
    static void TearDownTestSuite()
    {
        fs::remove_all(*root);
        delete root;
        delete part;
    }
    static std::string path(const std::string& name) { return (*root / name).string(); }
    static std::string video() { return haveFfmpeg() ? "" : " --set render.video=false"; }
    static fs::path* root;
    static test::TestPart* part;
};
fs::path* InspectTest::root = nullptr;
test::TestPart* InspectTest::part = nullptr;

TEST_F(InspectTest, VoidsCsvJsonCacheAndVisibility)
{
    const std::string study = path("study");
    const auto r = test::runFlyover("inspect " + path("part.nrrd") + " --study " + study + " " + QUICK + video() +
                                    " --quiet");
    ASSERT_EQ(r.exitCode, 0) << r.err;

    // voids.csv: the fixed header, one row per listed void.
    std::string header;
    const auto rows = readCsv(study + "/voids.csv", header);
    EXPECT_EQ(header, HEADER);
    const json j = readJson(study + "/voids.json");
    EXPECT_EQ(j.at("schema"), "flyover.voids/1");
    EXPECT_EQ(j.at("world_frame"), "LPS");
    EXPECT_EQ(j.at("threshold_source"), "otsu");
    EXPECT_GT(j.at("threshold").get<double>(), part->air);
    EXPECT_LT(j.at("threshold").get<double>(), part->material);
    ASSERT_TRUE(j.contains("porosity_percent"));
    ASSERT_TRUE(j.contains("small_void_count"));
    ASSERT_EQ(rows.size(), j.at("voids").size());
    ASSERT_EQ(rows.size(), part->voids.size()) << "listed voids: the test part has " << part->voids.size();
    for (std::size_t i = 0; i < rows.size(); ++i) {
        ASSERT_EQ(rows[i].size(), 10u) << "row " << i;
        const json& v = j.at("voids")[i];
        EXPECT_EQ(rows[i][0], std::to_string(v.at("id").get<int>()));
        EXPECT_EQ(rows[i][1], v.at("kind").get<std::string>());
        EXPECT_TRUE(rows[i][1] == "pore" || rows[i][1] == "crack") << rows[i][1];
        EXPECT_NEAR(std::stod(rows[i][2]), v.at("volume_mm3").get<double>(), 1e-3);
        EXPECT_NEAR(std::stod(rows[i][6]), v.at("centroid_x_mm").get<double>(), 1e-3);
    }
    // Each truth void is a row whose centroid (LPS mm) lies within a voxel of it.
    for (const auto& tv : part->voids) {
        const Vec3d c = part->centreMm(tv);
        double best = 1e9;
        for (const auto& row : rows)
            best = std::min(best, distance(c, Vec3d{std::stod(row[6]), std::stod(row[7]), std::stod(row[8])}));
        EXPECT_LT(best, part->voxelMm()) << "truth void at " << c.x << "," << c.y << "," << c.z;
    }

    // Every listed void shows in an OST overview and in no normal render.
    const json vis = readJson(study + "/overviews/visibility.json");
    EXPECT_EQ(vis.at("voids_unseen_in_ost"), 0);
    EXPECT_EQ(vis.at("voids_seen_in_normal"), 0);
    ASSERT_EQ(vis.at("voids").size(), rows.size());
    for (const auto& v : vis.at("voids")) {
        EXPECT_GT(v.at("ost_pixels_max").get<int64_t>(), 0) << v.dump();
        EXPECT_EQ(v.at("normal_pixels_total").get<int64_t>(), 0) << v.dump();
    }
    for (const char* view : {"anterior", "posterior", "left", "right", "superior", "inferior"}) {
        const RgbImage im = readPng(study + "/overviews/" + view + ".png");
        EXPECT_EQ(im.height, 128) << view;
        EXPECT_GT(im.width, 2 * 128) << view << ": OST | normal | legend";
    }
    EXPECT_TRUE(fs::exists(study + "/overviews/legend.json"));
    EXPECT_TRUE(fs::exists(study + "/overview.png"));
    const json manifest = readJson(study + "/manifest.json");
    EXPECT_EQ(manifest.at("pipeline"), "inspect");
    if (haveFfmpeg()) {
        EXPECT_GT(fs::file_size(study + "/turntable/turntable.mp4"), 1000u);
    }
    // The turntable is a real H.264 video with one frame per pose (ffprobe decodes it).
    if (haveFfmpeg() && std::system("command -v ffprobe >/dev/null 2>&1") == 0) {
        const std::string probe = path("probe.txt");
        ASSERT_EQ(std::system(("ffprobe -v error -count_frames -select_streams v:0 -show_entries "
                               "stream=codec_name,nb_read_frames -of default=nw=1 " +
                               study + "/turntable/turntable.mp4 > " + probe)
                                  .c_str()),
                  0);
        std::ifstream in(probe);
        std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        const std::size_t poses = readJson(study + "/turntable/poses.json").at("frames").size();
        EXPECT_GT(poses, 0u);
        EXPECT_NE(text.find("codec_name=h264"), std::string::npos) << "ffprobe: " << text;
        EXPECT_NE(text.find("nb_read_frames=" + std::to_string(poses) + "\n"), std::string::npos)
            << "expected " << poses << " decoded frames (poses.json); ffprobe: " << text;
    }

    // An unchanged re-run recomputes nothing.
    const auto again = test::runFlyover("inspect " + path("part.nrrd") + " --study " + study + " " + QUICK + video() +
                                        " --quiet");
    ASSERT_EQ(again.exitCode, 0) << again.err;
    for (const auto& [stage, was] : computed(readJson(study + "/manifest.json")))
        EXPECT_FALSE(was) << stage << " was recomputed on an unchanged re-run";

    // A render parameter of the overviews recomputes only the overviews.
    const auto px = test::runFlyover("inspect " + path("part.nrrd") + " --study " + study + " " + QUICK + video() +
                                     " --set render.overview_px=96 --quiet");
    ASSERT_EQ(px.exitCode, 0) << px.err;
    EXPECT_EQ(computed(readJson(study + "/manifest.json")),
              (std::map<std::string, bool>{{"ingest", false}, {"voids", false}, {"surfaces", false},
                                           {"overviews", true}, {"turntable", false}}));
    EXPECT_EQ(readPng(study + "/overviews/left.png").height, 96);

    // flyover status on a part study.
    const auto st = test::runFlyover("status --study " + study);
    EXPECT_EQ(st.exitCode, 0) << st.err;
    EXPECT_NE(st.out.find("voids"), std::string::npos) << st.out;
    EXPECT_EQ(st.out.find("stale"), std::string::npos) << st.out;
}

TEST_F(InspectTest, GivenThresholdIsUsedAndRecorded)
{
    const std::string study = path("given");
    const auto r = test::runFlyover("inspect " + path("part.nrrd") + " --study " + study +
                                    " --threshold 25000 --until voids --quiet");
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const json j = readJson(study + "/voids.json");
    EXPECT_EQ(j.at("threshold").get<double>(), 25000.0);
    EXPECT_EQ(j.at("threshold_source"), "given");
    EXPECT_FALSE(fs::exists(study + "/part_surface.ply")) << "--until voids ran the surfaces";
}

// The part phantom (flyover phantom --part, 128^3): every internal truth void is listed and shows
// in an OST overview, none in the normal render; the crack open to the surface is not listed.
TEST_F(InspectTest, PartPhantomEveryInternalVoidListedAndVisible)
{
    const auto ph = test::runFlyover("phantom " + path("phantom.nrrd") + " --part --size 128 --truth " +
                                     path("phantom_truth.json") + " --quiet");
    ASSERT_EQ(ph.exitCode, 0) << ph.err;
    const std::string study = path("phantom_study");
    const auto r = test::runFlyover("inspect " + path("phantom.nrrd") + " --study " + study +
                                    " --set render.video=false --set render.overview_px=192 --set render.supersample=1 "
                                    "--quiet");
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const json truth = readJson(path("phantom_truth.json"));
    const json voids = readJson(study + "/voids.json");
    const double voxelMm = voids.at("voxel_mm").get<double>();
    auto nearest = [&](const json& t) {
        const auto& c = t.at("centroid_lps_mm");
        const Vec3d tc{c[0].get<double>(), c[1].get<double>(), c[2].get<double>()};
        double best = 1e9;
        for (const auto& v : voids.at("voids"))
            best = std::min(best, distance(tc, Vec3d{v.at("centroid_x_mm").get<double>(), v.at("centroid_y_mm").get<double>(),
                                                     v.at("centroid_z_mm").get<double>()}));
        return best;
    };
    int internal = 0;
    for (const auto& t : truth.at("voids")) {
        if (t.at("internal").get<bool>()) {
            ++internal;
            EXPECT_LT(nearest(t), voxelMm) << "truth void " << t.dump() << " not listed";
        } else {
            EXPECT_GT(nearest(t), 4 * voxelMm) << "the open crack is listed as an internal void: " << t.dump();
        }
    }
    EXPECT_EQ(int(voids.at("voids").size()), internal);
    const json vis = readJson(study + "/overviews/visibility.json");
    for (const auto& v : vis.at("voids")) {
        EXPECT_GT(v.at("ost_pixels_max").get<int64_t>(), 0) << "shows in no OST overview: " << v.dump();
        EXPECT_EQ(v.at("normal_pixels_total").get<int64_t>(), 0) << "shows in the normal render: " << v.dump();
        EXPECT_GE(v.at("ost_rays_max").get<int64_t>(), v.at("ost_pixels_max").get<int64_t>()) << v.dump();
        EXPECT_EQ(v.at("normal_rays_total").get<int64_t>(), 0) << "a ray of the normal render meets it: " << v.dump();
    }
}

void expectOneLineRefusal(const test::CliResult& r, int code, const std::string& mustName)
{
    EXPECT_EQ(r.exitCode, code) << r.err;
    EXPECT_EQ(test::lineCount(r.err), 1) << r.err;
    EXPECT_EQ(r.err.rfind("flyover: error: ", 0), 0u) << r.err;
    EXPECT_NE(r.err.find(mustName), std::string::npos) << "the message should name " << mustName << ": " << r.err;
}

TEST_F(InspectTest, BadInputIsOneLineAndExit1)
{
    // No material: a threshold above every grey value. All material: below every grey value.
    expectOneLineRefusal(test::runFlyover("inspect " + path("part.nrrd") + " --study " + path("bad1") +
                                          " --threshold 65535.5 --quiet"),
                         1, "part.nrrd");
    expectOneLineRefusal(test::runFlyover("inspect " + path("part.nrrd") + " --study " + path("bad2") +
                                          " --threshold 1 --quiet"),
                         1, "part.nrrd");
    // A uniform block of material filling the whole scan (Otsu has nothing to split).
    {
        test::TestPart block = *part;
        std::fill(block.grey.begin(), block.grey.end(), uint16_t(40000));
        test::writeNrrdU16(path("block.nrrd"), block.geometry, block.grey);
        expectOneLineRefusal(test::runFlyover("inspect " + path("block.nrrd") + " --study " + path("bad3") + " --quiet"),
                             1, "block.nrrd");
    }
    test::writeNrrd2D(path("radiograph.nrrd"), 64, 48);
    expectOneLineRefusal(test::runFlyover("inspect " + path("radiograph.nrrd") + " --study " + path("bad4") + " --quiet"),
                         1, "radiograph.nrrd");
    test::writeNrrdRgb(path("colour.nrrd"), 16);
    expectOneLineRefusal(test::runFlyover("inspect " + path("colour.nrrd") + " --study " + path("bad5") + " --quiet"),
                         1, "colour.nrrd");
    expectOneLineRefusal(test::runFlyover("inspect " + path("missing.nrrd") + " --study " + path("bad6") + " --quiet"),
                         1, "missing.nrrd");
    // Unknown parameters, as in run: exit 2.
    expectOneLineRefusal(test::runFlyover("inspect " + path("part.nrrd") + " --study " + path("bad7") +
                                          " --set voids.no_such_thing=1 --quiet"),
                         2, "voids.no_such_thing");
    expectOneLineRefusal(test::runFlyover("inspect " + path("part.nrrd") + " --study " + path("bad8") +
                                          " --set segment.cleanse=false --quiet"),
                         2, "segment");
    // Nothing half-written that a later run trusts: no voids.csv after a refusal.
    EXPECT_FALSE(fs::exists(path("bad1") + "/voids.csv"));
}

} // namespace
} // namespace flyover

namespace flyover {
namespace {

/// Runs flyover with FLYOVER_CRASH_AT=point (the process kills itself there); its exit status.
int runCrashingAt(const std::string& point, const std::string& args)
{
    return std::system(("FLYOVER_CRASH_AT=" + point + " " + std::string(FLYOVER_BIN) + " " + args + " 2>/dev/null").c_str());
}

std::string statusLineOf(const std::string& out, const std::string& stage)
{
    std::istringstream in(out);
    for (std::string line; std::getline(in, line);)
        if (line.rfind(stage + " ", 0) == 0) return line;
    return "";
}

TEST_F(InspectTest, KilledRunLeavesAManifestOfTheFinishedStagesAndStatusTakesInspectParameters)
{
    const std::string study = path("killed");
    const std::string args = "inspect " + path("part.nrrd") + " --study " + study + " " + QUICK + video() + " --quiet";

    // Killed as the first stage's record is written: nothing finished, no manifest; status says
    // so and names both commands (it used to name 'flyover run' only).
    EXPECT_NE(runCrashingAt("stage:ingest:committed", args), 0);
    EXPECT_FALSE(fs::exists(study + "/manifest.json"));
    const auto none = test::runFlyover("status --study " + study);
    EXPECT_EQ(none.exitCode, 1);
    EXPECT_EQ(test::lineCount(none.err), 1) << none.err;
    EXPECT_NE(none.err.find("no stage of this study has finished yet"), std::string::npos) << none.err;
    EXPECT_NE(none.err.find("flyover inspect"), std::string::npos) << none.err;

    // Killed right after the surfaces stage's cache record: the manifest lists what finished
    // before (the voids stage at least), marked incomplete, and not the surfaces stage.
    EXPECT_NE(runCrashingAt("stage:surfaces:committed", args), 0);
    ASSERT_TRUE(fs::exists(study + "/manifest.json")) << "a killed run must leave the manifest of its finished stages";
    const json m = readJson(study + "/manifest.json");
    EXPECT_EQ(m.at("pipeline"), "inspect");
    EXPECT_EQ(m.at("complete"), false);
    std::map<std::string, json> listed;
    for (const auto& s : m.at("stages")) listed[s.at("stage").get<std::string>()] = s;
    EXPECT_TRUE(listed.count("voids")) << m.dump();
    EXPECT_FALSE(listed.count("surfaces")) << m.dump();
    EXPECT_FALSE(listed.count("overviews")) << m.dump();
    for (const auto& [stage, entry] : listed)
        for (auto it = entry.at("outputs").begin(); it != entry.at("outputs").end(); ++it)
            EXPECT_EQ(artifactDigest(study + "/" + it.key()), it.value().get<std::string>()) << stage << " " << it.key();
    const auto st = test::runFlyover("status --study " + study);
    ASSERT_EQ(st.exitCode, 0) << st.err;
    EXPECT_NE(statusLineOf(st.out, "voids").find("fresh"), std::string::npos) << st.out;
    // Its record was committed before the kill: the cache has it, the run restores nothing.
    EXPECT_NE(statusLineOf(st.out, "surfaces").find("fresh"), std::string::npos) << st.out;
    EXPECT_NE(statusLineOf(st.out, "overviews").find("not finished by the last run"), std::string::npos) << st.out;

    // The run finishes; status with inspect's --set (a render parameter of the overviews).
    const auto r = test::runFlyover(args);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const json done = readJson(study + "/manifest.json");
    EXPECT_EQ(done.at("complete"), true);
    EXPECT_EQ(done.at("stages").size(), 5u);
    EXPECT_EQ(computed(done).at("voids"), false) << "the killed run's voids are reused";
    const auto set = test::runFlyover("status --study " + study + " " + QUICK + video() + " --set render.overview_px=96");
    ASSERT_EQ(set.exitCode, 0) << set.err;
    EXPECT_NE(statusLineOf(set.out, "overviews").find("stale"), std::string::npos) << set.out;
    EXPECT_NE(statusLineOf(set.out, "overviews").find("render.overview_px"), std::string::npos) << set.out;
    EXPECT_NE(statusLineOf(set.out, "turntable").find("fresh"), std::string::npos) << set.out;
    EXPECT_NE(statusLineOf(set.out, "voids").find("fresh"), std::string::npos) << set.out;
    const auto threshold = test::runFlyover("status --study " + study + " --set voids.threshold=20000");
    ASSERT_EQ(threshold.exitCode, 0) << threshold.err;
    EXPECT_NE(statusLineOf(threshold.out, "voids").find("voids.threshold"), std::string::npos) << threshold.out;
    const auto bad = test::runFlyover("status --study " + study + " --set voids.no_such=1");
    EXPECT_EQ(bad.exitCode, 2) << bad.err;
    EXPECT_EQ(test::lineCount(bad.err), 1) << bad.err;
}

// `flyover stage` (workflow engines) runs inspect's stages one by one: inspect:NAME, or the plain
// name once the study says it is a part study; a receipt per stage; upstream checked with
// inspect's parameters; a colon stage or parameter refused on a part study.
TEST_F(InspectTest, StageCommandRunsInspectStagesOneByOne)
{
    const std::string study = path("staged");
    const std::string args = " --study " + study + " " + QUICK + video();
    auto receipt = [&](const std::string& stage) { return readJson(study + "/stages/" + stage + ".json"); };

    const auto early = test::runFlyover("-q stage inspect:voids" + args + " --ct " + path("part.nrrd"));
    EXPECT_EQ(early.exitCode, 4) << "voids before ingest: not ready; " << early.err;
    EXPECT_NE(early.err.find("inspect:ingest"), std::string::npos) << early.err;

    const auto ingest = test::runFlyover("-q stage inspect:ingest" + args + " --ct " + path("part.nrrd"));
    ASSERT_EQ(ingest.exitCode, 0) << ingest.err;
    EXPECT_EQ(readJson(study + "/manifest.json").at("pipeline"), "inspect");
    // Plain names from here on: the manifest says it is a part study (the CT too comes from it).
    for (const char* stage : {"voids", "inspect:surfaces", "overviews", "inspect:turntable"}) {
        const auto r = test::runFlyover(std::string("-q stage ") + stage + args);
        ASSERT_EQ(r.exitCode, 0) << stage << ": " << r.err;
    }
    for (const char* stage : {"ingest", "voids", "surfaces", "overviews", "turntable"}) {
        const json rec = receipt(stage);
        EXPECT_EQ(rec.value("status", ""), "ok") << stage << ": " << rec.dump();
        EXPECT_EQ(rec.value("stage", ""), stage);
        EXPECT_TRUE(rec.value("computed", false)) << stage << " was not computed by its own call";
        EXPECT_FALSE(rec.at("outputs").empty()) << rec.dump();
    }
    EXPECT_TRUE(fs::exists(study + "/voids.csv"));
    EXPECT_TRUE(fs::exists(study + "/overviews/visibility.json"));

    // `flyover inspect` with the same parameters finds everything done.
    const auto whole = test::runFlyover("inspect " + path("part.nrrd") + args + " --quiet");
    ASSERT_EQ(whole.exitCode, 0) << whole.err;
    for (const auto& [stage, was] : computed(readJson(study + "/manifest.json")))
        EXPECT_FALSE(was) << stage << " recomputed after flyover stage made it";

    // An inspect parameter upstream changed: the surfaces cannot run (voids stale), exit 4.
    const auto stale = test::runFlyover("-q stage surfaces" + args + " --set voids.threshold=20000");
    EXPECT_EQ(stale.exitCode, 4) << stale.err;
    EXPECT_NE(stale.err.find("voids"), std::string::npos) << stale.err;
    // A colon parameter or stage on a part study: refused in one line.
    const auto colonParam = test::runFlyover("-q stage voids" + args + " --set segment.cleanse=false");
    EXPECT_EQ(colonParam.exitCode, 2) << colonParam.err;
    EXPECT_EQ(test::lineCount(colonParam.err), 1) << colonParam.err;
    const auto colonStage = test::runFlyover("-q stage segment" + args);
    EXPECT_EQ(colonStage.exitCode, 2) << colonStage.err;
    EXPECT_NE(colonStage.err.find("unknown inspect stage"), std::string::npos) << colonStage.err;
    const auto unknown = test::runFlyover("-q stage inspect:segment --study " + path("nowhere"));
    EXPECT_EQ(unknown.exitCode, 2) << unknown.err;
}

} // namespace
} // namespace flyover
