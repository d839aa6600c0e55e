// The render stage as cached steps (issue 15): each step keyed by its own parameters, the first
// fly-over pair written and announced first, and `flyover status` comparing the study's files
// with the record (a study whose frames/ holds another parameter set's output is not fresh).

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/run_log.h"
#include "study_fixture.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <set>
#include <sstream>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

std::string statusOf(const std::vector<StageStatus>& st, const std::string& stage)
{
    for (const auto& s : st)
        if (s.stage == stage) return s.state + (s.reason.empty() ? "" : ": " + s.reason);
    return "?";
}

bool haveFfmpeg() { return std::system("command -v ffmpeg >/dev/null 2>&1") == 0; }

} // namespace

TEST_F(StudyTest, VideoFpsRecomputesTheVideoOnly)
{
    if (!haveFfmpeg()) GTEST_SKIP() << "no ffmpeg on PATH";
    RunOptions o = options("fps");
    o.params.render.video = true;
    const auto first = runPipeline(o);
    ASSERT_TRUE(fs::exists(o.studyDir + "/video/flyover.mp4"));
    EXPECT_EQ(readJson(o.studyDir + "/video/poses.json").at("fps"), 25);
    // The video takes the pairs the frames step rendered in the same run (the same cameras)
    // from frames/: as many as the two steps' centerline indices have in common.
    auto videoReport = [&] {
        const nlohmann::json manifest = readJson(o.studyDir + "/manifest.json");
        for (const auto& st : manifest.at("stages"))
            if (st.at("stage") == "video") return st.at("report");
        return nlohmann::json();
    };
    {
        std::set<std::size_t> frameIndices;
        const nlohmann::json framePoses = readJson(o.studyDir + "/frames/poses.json");
        const nlohmann::json videoPoses = readJson(o.studyDir + "/video/poses.json");
        for (const auto& f : framePoses.at("frames")) frameIndices.insert(f.at("centerline_index").get<std::size_t>());
        std::size_t common = 0;
        for (const auto& f : videoPoses.at("frames"))
            common += frameIndices.count(f.at("centerline_index").get<std::size_t>());
        EXPECT_GT(common, 0u);
        EXPECT_EQ(videoReport().value("frames_from_frame_pairs", std::size_t(0)), common);
    }

    o.params.render.videoFps = 12;
    const auto second = runPipeline(o);
    const auto m = computedStages(second);
    EXPECT_EQ(m, (std::map<std::string, bool>{{"ingest", false}, {"segment", false}, {"centerline", false},
                                              {"mesh", false}, {"frames", false}, {"flythrough", false},
                                              {"overviews", false}, {"video", true}, {"coverage", false}}))
        << "render.video_fps changed: only the video may be recomputed";
    EXPECT_EQ(readJson(o.studyDir + "/video/poses.json").at("fps"), 12);
    EXPECT_EQ(videoReport().value("frames_from_frame_pairs", std::size_t(1)), 0u)
        << "the frames step did not run: every video frame is rendered";
    EXPECT_NE(outputDigests(first)["video"], outputDigests(second)["video"]);
    for (const char* step : {"frames", "flythrough", "overviews", "coverage"})
        EXPECT_EQ(outputDigests(first)[step], outputDigests(second)[step]) << step;

    StatusOptions so;
    so.studyDir = o.studyDir;
    for (const auto& st : studyStatus(so)) EXPECT_EQ(st.state, "fresh") << st.stage << ": " << st.reason;
    so.params = o.params;
    so.paramsGiven = true;
    so.params.render.videoFps = 30;
    const auto st = studyStatus(so);
    EXPECT_EQ(statusOf(st, "frames"), "fresh");
    EXPECT_EQ(statusOf(st, "coverage"), "fresh");
    EXPECT_NE(statusOf(st, "video").find("render.video_fps"), std::string::npos) << statusOf(st, "video");
}

TEST_F(StudyTest, FirstPairIsWrittenAndAnnouncedBeforeTheOtherRenderSteps)
{
    RunOptions o = options("firstpair");
    std::ostringstream out;
    RunLog log(RunLog::Mode::Json, out);
    o.log = &log;
    runPipeline(o);

    std::vector<nlohmann::json> events;
    std::istringstream lines(out.str());
    for (std::string line; std::getline(lines, line);) events.push_back(nlohmann::json::parse(line));
    std::size_t firstPair = events.size();
    for (std::size_t i = 0; i < events.size(); ++i)
        if (events[i].at("event") == "first_pair") {
            EXPECT_EQ(firstPair, events.size()) << "announced twice";
            firstPair = i;
        }
    ASSERT_LT(firstPair, events.size()) << "no first_pair event in:\n" << out.str();
    const auto& e = events[firstPair];
    EXPECT_EQ(e.at("path"), o.studyDir + "/frames/pair_0000.png");
    EXPECT_GT(e.at("seconds_since_start").get<double>(), 0.0);
    EXPECT_TRUE(fs::exists(e.at("path").get<std::string>()));
    for (std::size_t i = 0; i < firstPair; ++i) {
        const std::string stage = events[i].value("stage", "");
        EXPECT_FALSE(stage != "frames" && std::find(RENDER_STEPS.begin(), RENDER_STEPS.end(), stage) != RENDER_STEPS.end())
            << "render step " << stage << " ran before the first pair was announced: " << events[i].dump();
        EXPECT_FALSE(events[i].at("event") == "stage_finished" && stage == "frames") << "frames finished first";
    }
    // An unchanged re-run renders nothing and announces nothing.
    std::ostringstream out2;
    RunLog log2(RunLog::Mode::Json, out2);
    o.log = &log2;
    runPipeline(o);
    EXPECT_EQ(out2.str().find("first_pair"), std::string::npos) << out2.str();
}

TEST_F(StudyTest, StatusComparesTheStudysFilesWithTheRecord)
{
    RunOptions o = options("otherparams");
    runPipeline(o);
    const std::string framesA = artifactDigest(o.studyDir + "/frames");

    // Other frame parameters on a copy of the study (as render_bench works): the study itself
    // is untouched and stays fresh.
    const std::string copy = studyDir("otherparams-copy");
    copyStudy(o.studyDir, copy);
    RunOptions b = o;
    b.studyDir = copy;
    b.params.render.frameStepMm = 60;
    runPipeline(b);
    EXPECT_NE(artifactDigest(copy + "/frames"), framesA) << "the copy's frames must be other frames";
    EXPECT_EQ(artifactDigest(o.studyDir + "/frames"), framesA) << "working on the copy changed the study";
    StatusOptions so;
    so.studyDir = o.studyDir;
    so.params = o.params;
    so.paramsGiven = true;
    for (const auto& st : studyStatus(so)) EXPECT_EQ(st.state, "fresh") << st.stage << ": " << st.reason;
    EXPECT_THROW(copyStudy(o.studyDir, copy), InputError) << "copying onto an existing folder";

    // The same run in the study itself leaves frames/ holding the other parameters' output:
    // status against the first parameters must say so, not "fresh".
    b.studyDir = o.studyDir;
    runPipeline(b);
    const std::string frames = statusOf(studyStatus(so), "frames");
    EXPECT_EQ(frames.rfind("stale", 0), 0u) << frames;
    EXPECT_NE(frames.find("other frames parameters"), std::string::npos) << frames;
    // A run with the first parameters restores them from the cache.
    const auto m = computedStages(runPipeline(o));
    EXPECT_FALSE(m.at("frames"));
    EXPECT_EQ(artifactDigest(o.studyDir + "/frames"), framesA);
    EXPECT_EQ(statusOf(studyStatus(so), "frames"), "fresh");

    // A frames/ changed by hand (one pair more) is not fresh either.
    fs::copy_file(o.studyDir + "/frames/pair_0000.png", o.studyDir + "/frames/pair_9999.png");
    const std::string edited = statusOf(studyStatus(so), "frames");
    EXPECT_NE(edited.find("modified"), std::string::npos) << edited;
}
