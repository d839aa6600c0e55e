// Re-runs, cache keys, corruption and crash safety of a study (TBB dataflow with a
// content-addressed per-stage cache).

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "tests/pipeline/study_fixture.h"
#include "volume/error.h"
#include "volume/image_io.h"

#include <tbb/global_control.h>

#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <random>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

const std::map<std::string, bool> ALL_COMPUTED =
    withRenderSteps({{"ingest", true}, {"segment", true}, {"centerline", true}, {"mesh", true}}, true);
const std::map<std::string, bool> NONE_COMPUTED =
    withRenderSteps({{"ingest", false}, {"segment", false}, {"centerline", false}, {"mesh", false}}, false);

std::string describe(const std::map<std::string, bool>& m)
{
    std::string s;
    for (const auto& [k, v] : m) s += k + (v ? "=computed " : "=reused ");
    return s;
}

std::vector<std::string> temporaries(const fs::path& dir)
{
    std::vector<std::string> found;
    for (const auto& e : fs::recursive_directory_iterator(dir))
        if (e.path().filename().string().rfind(".tmp-", 0) == 0) found.push_back(e.path().string());
    return found;
}

std::string statusOf(const std::vector<StageStatus>& st, const std::string& stage)
{
    for (const auto& s : st)
        if (s.stage == stage) return s.state + (s.reason.empty() ? "" : ": " + s.reason);
    return "?";
}

} // namespace

TEST_F(StudyTest, UnchangedRerunRecomputesNothing)
{
    const RunOptions o = options("rerun");
    const auto first = runPipeline(o);
    EXPECT_EQ(computedStages(first), ALL_COMPUTED) << describe(computedStages(first));
    const auto second = runPipeline(o);
    EXPECT_EQ(computedStages(second), NONE_COMPUTED) << describe(computedStages(second));
    EXPECT_EQ(outputDigests(first), outputDigests(second));
    for (std::size_t i = 0; i < first["stages"].size(); ++i)
        EXPECT_EQ(first["stages"][i]["key"], second["stages"][i]["key"]) << first["stages"][i]["stage"];
    StatusOptions so;
    so.studyDir = o.studyDir;
    for (const auto& st : studyStatus(so)) EXPECT_EQ(st.state, "fresh") << st.stage << ": " << st.reason;
}

TEST_F(StudyTest, ParameterChangesRecomputeExactlyWhatDependsOnThem)
{
    RunOptions o = options("params");
    runPipeline(o);

    // The roll moves the fly-over cameras: frames, video and coverage; not the fly-through
    // pairs, the overviews nor the polyps' pairs (turned to face each candidate).
    o.params.render.rollDeg = 30;
    auto m = computedStages(runPipeline(o));
    EXPECT_EQ(m, (std::map<std::string, bool>{{"ingest", false}, {"segment", false}, {"centerline", false},
                                              {"mesh", false}, {"frames", true}, {"flythrough", false},
                                              {"overviews", false}, {"video", true}, {"coverage", true},
                                              {"polyps", false}}))
        << "render.roll_deg changed: " << describe(m);

    o.params.segment.surfaceIsoHu = -450;
    m = computedStages(runPipeline(o));
    EXPECT_EQ(m, withRenderSteps({{"ingest", false}, {"segment", true}, {"centerline", true}, {"mesh", true}}, true))
        << "segment.surface_iso_hu changed: " << describe(m);

    // Keys are over input *content*: a segmentation parameter whose change leaves the lumen
    // identical recomputes segment only (an early cut-off, like a build system's).
    o.params.segment.airThresholdHu = -790;
    const auto before = outputDigests(readJson(o.studyDir + "/manifest.json"));
    const auto after = runPipeline(o);
    m = computedStages(after);
    EXPECT_TRUE(m["segment"]);
    if (outputDigests(after)["segment"] == before.at("segment")) {
        EXPECT_EQ(m, withRenderSteps({{"ingest", false}, {"segment", true}, {"centerline", false}, {"mesh", false}},
                                     false))
            << "identical lumen, yet downstream recomputed: " << describe(m);
    }
}

TEST_F(StudyTest, SwitchingAParameterBackReusesTheEarlierResult)
{
    RunOptions o = options("backforth");
    const auto a = runPipeline(o);
    o.params.render.rollDeg = 45;
    const auto b = runPipeline(o);
    EXPECT_TRUE(computedStages(b)["frames"]);
    EXPECT_NE(outputDigests(a)["frames"], outputDigests(b)["frames"]) << "a 45 degree roll must change the frames";
    o.params.render.rollDeg = 0;
    const auto c = runPipeline(o);
    EXPECT_EQ(computedStages(c), NONE_COMPUTED) << describe(computedStages(c));
    EXPECT_EQ(outputDigests(a), outputDigests(c));
    // The study's files are the first result again.
    EXPECT_EQ(artifactDigest(o.studyDir + "/frames"), outputDigests(a)["frames"]["frames"].get<std::string>());
}

TEST_F(StudyTest, ScanContentNotMtimeDecides)
{
    const fs::path ct = fs::path(studyDir("scan-ct.nii.gz"));
    fs::copy_file(ctPath(), ct);
    RunOptions o = options("scan");
    o.ctPath = ct.string();
    runPipeline(o);

    fs::last_write_time(ct, fs::file_time_type::clock::now() + std::chrono::hours(1));
    auto m = computedStages(runPipeline(o));
    EXPECT_EQ(m, NONE_COMPUTED) << "touching the scan's mtime: " << describe(m);

    // New content: a different phantom seed.
    PhantomParams pp;
    pp.seed = STUDY_SEED + 1;
    writePhantom(makePhantom(pp), pp, ct.string(), "", "");
    m = computedStages(runPipeline(o));
    EXPECT_EQ(m, ALL_COMPUTED) << "changing the scan's content: " << describe(m);
}

TEST_F(StudyTest, CorruptOrTruncatedArtifactsAreReportedAndRecomputed)
{
    const RunOptions o = options("corrupt");
    const auto clean = runPipeline(o);
    StatusOptions so;
    so.studyDir = o.studyDir;

    // Flip one byte in the middle of the surface (in place: the cached object shares the inode).
    {
        const std::string ply = o.studyDir + "/surface.ply";
        std::fstream f(ply, std::ios::in | std::ios::out | std::ios::binary);
        f.seekg(static_cast<std::streamoff>(fs::file_size(ply) / 2));
        char c = 0;
        f.read(&c, 1);
        c = static_cast<char>(c ^ 0x10);
        f.seekp(static_cast<std::streamoff>(fs::file_size(ply) / 2));
        f.write(&c, 1);
    }
    auto st = studyStatus(so);
    EXPECT_NE(statusOf(st, "mesh").find("corrupt"), std::string::npos) << statusOf(st, "mesh");
    EXPECT_EQ(statusOf(st, "segment"), "fresh");
    auto m = runPipeline(o);
    EXPECT_TRUE(computedStages(m)["mesh"]) << describe(computedStages(m));
    EXPECT_FALSE(computedStages(m)["segment"]);
    EXPECT_EQ(outputDigests(m)["mesh"], outputDigests(clean)["mesh"]) << "the recomputed surface equals the original";

    // Truncate the centerline (a new file: the object in the cache stays intact).
    {
        const std::string cl = o.studyDir + "/centerline.json";
        const auto size = fs::file_size(cl);
        fs::remove(cl);
        std::ofstream(cl) << std::string(size / 2, ' ');
    }
    st = studyStatus(so);
    EXPECT_NE(statusOf(st, "centerline").find("corrupt"), std::string::npos) << statusOf(st, "centerline");
    m = runPipeline(o);
    EXPECT_EQ(outputDigests(m), outputDigests(clean));
    EXPECT_EQ(artifactDigest(o.studyDir + "/centerline.json"), outputDigests(clean)["centerline"]["centerline.json"]);

    // A removed artifact is reported as missing.
    fs::remove(o.studyDir + "/overview.png");
    st = studyStatus(so);
    EXPECT_NE(statusOf(st, "overviews").find("missing"), std::string::npos) << statusOf(st, "overviews");
    EXPECT_EQ(statusOf(st, "frames"), "fresh");
    runPipeline(o);
    EXPECT_TRUE(fs::exists(o.studyDir + "/overview.png"));
}

TEST_F(StudyTest, StatusSaysWhyAStageIsStale)
{
    const RunOptions o = options("status");
    runPipeline(o);
    StatusOptions so;
    so.studyDir = o.studyDir;
    so.params = o.params;
    so.paramsGiven = true;
    so.params.centerline.stepMm = 2.0;
    const auto st = studyStatus(so);
    EXPECT_EQ(statusOf(st, "ingest"), "fresh");
    EXPECT_EQ(statusOf(st, "mesh"), "fresh");
    EXPECT_NE(statusOf(st, "centerline").find("parameters changed (centerline.step_mm)"), std::string::npos)
        << statusOf(st, "centerline");
    for (const auto& step : RENDER_STEPS) EXPECT_EQ(statusOf(st, step).rfind("stale", 0), 0u) << statusOf(st, step);
    StatusOptions none;
    none.studyDir = studyDir("not-a-study");
    fs::create_directories(none.studyDir);
    EXPECT_THROW(studyStatus(none), InputError);
}

TEST_F(StudyTest, UntilAndForceSelectStages)
{
    RunOptions o = options("until");
    o.untilStage = "mesh";
    auto m = computedStages(runPipeline(o));
    EXPECT_EQ(m, (std::map<std::string, bool>{{"ingest", true}, {"segment", true}, {"mesh", true}}))
        << describe(m);
    EXPECT_FALSE(fs::exists(o.studyDir + "/centerline.json"));
    o.untilStage.clear();
    o.forceStage = "mesh";
    m = computedStages(runPipeline(o));
    EXPECT_EQ(m, withRenderSteps({{"ingest", false}, {"segment", false}, {"centerline", true}, {"mesh", true}}, true))
        << describe(m);
    // "render" names the render steps; forcing one step recomputes it alone.
    o.forceStage = "video";
    m = computedStages(runPipeline(o));
    EXPECT_EQ(m, (std::map<std::string, bool>{{"ingest", false}, {"segment", false}, {"centerline", false},
                                              {"mesh", false}, {"frames", false}, {"flythrough", false},
                                              {"overviews", false}, {"video", true}, {"coverage", false},
                                              {"polyps", false}}))
        << describe(m);
    o.forceStage = "render";
    m = computedStages(runPipeline(o));
    EXPECT_EQ(m, withRenderSteps({{"ingest", false}, {"segment", false}, {"centerline", false}, {"mesh", false},
                                  {"polyps", false}},
                                 true))
        << describe(m);
    o.forceStage = "nonsense";
    EXPECT_THROW(runPipeline(o), ParameterError);
}

TEST_F(StudyTest, SameDigestsOnOneAndTwoThreads)
{
    nlohmann::json one, two;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = runPipeline(options("threads1"));
    }
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
        two = runPipeline(options("threads2"));
    }
    const auto a = outputDigests(one), b = outputDigests(two);
    for (const auto& [stage, digests] : a) EXPECT_EQ(digests, b.at(stage)) << "stage " << stage;
}

TEST_F(StudyTest, LockedStudyIsRefusedWithAClearMessage)
{
    const RunOptions o = options("locked");
    fs::create_directories(o.studyDir);
    StudyLock held(o.studyDir, false);
    try {
        runPipeline(o);
        FAIL() << "a second run on a locked study was accepted";
    } catch (const StudyBusy& e) {
        EXPECT_NE(std::string(e.what()).find("another flyover run"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(o.studyDir + "/ct.vdb"));
}

TEST_F(StudyTest, CacheIsCappedWithLeastRecentlyUsedEviction)
{
    RunOptions o = options("evict");
    runPipeline(o);
    ArtifactStore store(o.studyDir);
    const uint64_t oneResult = store.objectBytes();
    const uint64_t renderBytes = fs::file_size(o.studyDir + "/overview.png") + [&] {
        uint64_t n = 0;
        for (const auto& e : fs::directory_iterator(o.studyDir + "/frames")) n += fs::file_size(e.path());
        return n;
    }();
    // Three renders with different rolls, under a cap that holds one full result and half a
    // render: the older render results go, the current ones stay and the study stays complete.
    o.cacheMaxGb = (oneResult + renderBytes / 2) / 1e9;
    for (double roll : {10.0, 20.0, 30.0}) {
        o.params.render.rollDeg = roll;
        runPipeline(o);
    }
    EXPECT_LE(store.objectBytes(), static_cast<uint64_t>(o.cacheMaxGb * 1e9) + 1);
    o.params.render.rollDeg = 30;
    EXPECT_EQ(computedStages(runPipeline(o)), NONE_COMPUTED) << "the latest result survived eviction";
    o.params.render.rollDeg = 10;
    EXPECT_TRUE(computedStages(runPipeline(o))["frames"]) << "the oldest frames were evicted";
}

TEST_F(StudyTest, FailingStageIsNamedAndNothingDownstreamRuns)
{
    // A scan of pure air: ingest keeps no voxel.
    Image3<int16_t> air;
    air.geometry.size = {32, 32, 32};
    air.voxels.assign(32 * 32 * 32, -1000);
    const std::string path = studyDir("air.nii.gz");
    writeImage(air, path);
    RunOptions o = options("air");
    o.ctPath = path;
    try {
        runPipeline(o);
        FAIL() << "an all-air scan was accepted";
    } catch (const StageError& e) {
        EXPECT_EQ(e.stageName, "ingest") << e.what();
    }
    EXPECT_FALSE(fs::exists(o.studyDir + "/lumen.vdb"));
    EXPECT_TRUE(temporaries(o.studyDir).empty());
}

TEST_F(StudyTest, KilledRunsLeaveNothingThatLies)
{
    // Reference: an uninterrupted run through the command line.
    const std::string flyover = FLYOVER_BIN;
    const std::string common = " --set render.width_px=96 --set render.height_px=96 --set render.frame_step_mm=150"
                               " --set render.overview_px=128";
    const std::string ref = studyDir("kill-ref");
    ASSERT_EQ(std::system((flyover + " -q run " + ctPath() + " --study " + ref + common).c_str()), 0);
    const auto refDigests = outputDigests(readJson(ref + "/manifest.json"));

    std::mt19937 rng(1234);
    const std::string study = studyDir("kill");
    for (int trial = 0; trial < 6; ++trial) {
        const int delayMs = std::uniform_int_distribution<int>(50, 2500)(rng);
        const pid_t pid = ::fork();
        ASSERT_GE(pid, 0);
        if (pid == 0) {
            const std::string cmd = flyover + " -q run " + ctPath() + " --study " + study + common;
            ::execl("/bin/sh", "sh", "-c", ("exec " + cmd).c_str(), static_cast<char*>(nullptr));
            ::_exit(127);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(delayMs));
        ::kill(pid, SIGKILL);
        int status = 0;
        ::waitpid(pid, &status, 0);
    }
    ASSERT_EQ(std::system((flyover + " -q run " + ctPath() + " --study " + study + common).c_str()), 0);
    EXPECT_TRUE(temporaries(study).empty()) << temporaries(study).front();

    // Exact kill points: mid-write (temporary file complete, not yet renamed), between a
    // cache object and its record, and right after a stage's record, each on a fresh study.
    for (const char* point : {"atomic-write:before-rename", "store:objects-linked", "stage:segment:committed",
                              "frames:first-pair", "stage:frames:committed", "stage:video:committed",
                              // write-behind: mesh's files still in their temporaries, and
                              // ingest's record after its file, both while later stages run;
                              // mesh's report completed behind (its checks), nothing recorded
                              "writebehind:mesh:before-finish", "writebehind:mesh:report-completed",
                              // mesh's files renamed at the first pair, not yet fsynced nor
                              // recorded: the next run must not trust them (no record)
                              "writebehind:mesh:renamed",
                              "stage:ingest:committed",
                              // the first pair out, ct.vdb still in its temporary (the fsyncs
                              // and renames wait for the first pair)
                              "writebehind:ingest:before-finish"}) {
        const std::string s = studyDir(std::string("crash-") + point);
        const int killed = std::system(("FLYOVER_CRASH_AT=" + std::string(point) + " " + flyover + " -q run " +
                                        ctPath() + " --study " + s + common + " 2>/dev/null").c_str());
        EXPECT_NE(killed, 0) << "the run did not reach crash point " << point;
        ASSERT_EQ(std::system((flyover + " -q run " + ctPath() + " --study " + s + common).c_str()), 0) << point;
        EXPECT_TRUE(temporaries(s).empty()) << point << ": " << temporaries(s).front();
        EXPECT_EQ(outputDigests(readJson(s + "/manifest.json")), refDigests) << "after a crash at " << point;
    }
    {
        // The write-behind renames at the first pair's announcement (an open viewer reads the
        // study then) and records only after the fsyncs: killed in between, surface.ply is
        // under its name with no mesh record, so the next run does not trust it.
        const std::string s = studyDir("crash-renamed-look");
        const int killed = std::system(("FLYOVER_CRASH_AT=writebehind:mesh:renamed " + flyover + " -q run " +
                                        ctPath() + " --study " + s + common + " 2>/dev/null").c_str());
        EXPECT_NE(killed, 0);
        EXPECT_TRUE(fs::is_regular_file(s + "/surface.ply")) << "renamed before the crash point";
        bool meshRecord = false;
        for (const auto& e : fs::directory_iterator(s + "/.flyover/records"))
            meshRecord = meshRecord || e.path().filename().string().rfind("mesh-", 0) == 0;
        EXPECT_FALSE(meshRecord) << "a mesh record written before its files were fsynced";
    }
    const auto digests = outputDigests(readJson(study + "/manifest.json"));
    EXPECT_EQ(digests, refDigests) << "a run after kill -9 must give the uninterrupted run's artifacts";
    for (const auto& [stage, outputs] : digests)
        for (auto it = outputs.begin(); it != outputs.end(); ++it)
            EXPECT_EQ(artifactDigest(study + "/" + it.key()), it.value().get<std::string>()) << it.key();
}
