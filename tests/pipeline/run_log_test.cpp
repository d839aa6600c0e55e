#include "pipeline/run_log.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <sstream>

using namespace flyover;

TEST(RunLog, PlainModeWritesOneLinePerEvent)
{
    std::ostringstream out;
    {
        RunLog log(RunLog::Mode::Plain, out);
        log.stageStarted("segment");
        log.stageProgress("segment", 0.5, "components");  // plain mode: no progress lines
        log.stageFinished("segment", true, 1.25, "");
        log.stageFinished("ingest", false, 0.01, "");
    }
    EXPECT_EQ(out.str(), "flyover: segment: running\n"
                         "flyover: segment: computed in 1.25 s\n"
                         "flyover: ingest: reused from the cache\n");
}

TEST(RunLog, JsonModeWritesParseableLines)
{
    std::ostringstream out;
    {
        RunLog log(RunLog::Mode::Json, out);
        log.stageStarted("mesh");
        log.stageProgress("mesh", 0.25, "extracting");
        log.stageFinished("mesh", true, 2.0, "");
        log.message("done");
    }
    std::istringstream in(out.str());
    std::string line;
    std::vector<nlohmann::json> events;
    while (std::getline(in, line)) events.push_back(nlohmann::json::parse(line));
    ASSERT_EQ(events.size(), 4u) << out.str();
    EXPECT_EQ(events[0]["event"], "stage_started");
    EXPECT_EQ(events[1]["event"], "progress");
    EXPECT_DOUBLE_EQ(events[1]["fraction"].get<double>(), 0.25);
    EXPECT_EQ(events[2]["event"], "stage_finished");
    EXPECT_EQ(events[2]["computed"], true);
    EXPECT_EQ(events[3]["text"], "done");
    for (const auto& e : events) EXPECT_TRUE(e.contains("time"));
}

TEST(RunLog, BarsModeDrawsOneBarPerRunningStageWithEta)
{
    std::ostringstream out;
    {
        RunLog log(RunLog::Mode::Bars, out);
        log.stageStarted("centerline");
        log.stageStarted("mesh");
        log.stageProgress("mesh", 0.5, "smoothing");
        const std::string s = out.str();
        EXPECT_NE(s.find("centerline"), std::string::npos);
        EXPECT_NE(s.find("mesh"), std::string::npos);
        EXPECT_NE(s.find('['), std::string::npos) << "a bar is drawn";
        EXPECT_NE(s.find("ETA"), std::string::npos);
        EXPECT_NE(s.find("\x1b[1A"), std::string::npos) << "bars are redrawn in place";
        log.stageFinished("mesh", true, 1.0, "");
        log.stageFinished("centerline", true, 1.0, "");
    }
    EXPECT_NE(out.str().find("mesh: computed in"), std::string::npos);
}

TEST(RunLog, QuietModeWritesNothing)
{
    std::ostringstream out;
    {
        RunLog log(RunLog::Mode::Quiet, out);
        log.stageStarted("render");
        log.stageProgress("render", 0.5, "frames");
        log.stageFinished("render", true, 1.0, "");
        log.message("hello");
    }
    EXPECT_TRUE(out.str().empty());
}

TEST(RunLog, FirstPairIsALineOrAJsonEventWithTheTimeSinceStart)
{
    std::ostringstream plain, json, quiet;
    {
        RunLog p(RunLog::Mode::Plain, plain), j(RunLog::Mode::Json, json), q(RunLog::Mode::Quiet, quiet);
        p.firstPair("/s/frames/pair_0000.png");
        j.firstPair("/s/frames/pair_0000.png");
        q.firstPair("/s/frames/pair_0000.png");
    }
    EXPECT_EQ(plain.str().rfind("flyover: first fly-over pair: /s/frames/pair_0000.png (", 0), 0u) << plain.str();
    EXPECT_NE(plain.str().find(" s after start)\n"), std::string::npos) << plain.str();
    EXPECT_NE(plain.str().find("\nflyover: read the study now: flyover view --study /s\n"), std::string::npos)
        << "the first pair line names the viewer of the study; saw: " << plain.str();
    const auto e = nlohmann::json::parse(json.str());
    EXPECT_EQ(e["event"], "first_pair");
    EXPECT_EQ(e["path"], "/s/frames/pair_0000.png");
    EXPECT_GE(e["seconds_since_start"].get<double>(), 0.0);
    EXPECT_LT(e["seconds_since_start"].get<double>(), 60.0);
    EXPECT_TRUE(quiet.str().empty());
}
