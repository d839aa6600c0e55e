// LiveStudy (view/live_study.h): `flyover view` on a study that a run is still computing, and
// the reload of a served study whose files change.
#include "view_fixture.h"

#include "pipeline/artifact_store.h"
#include "view/live_study.h"
#include "volume/error.h"

#include <chrono>
#include <filesystem>
#include <functional>
#include <sstream>
#include <thread>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover::test {
namespace {

constexpr LiveStudy::Options FAST{0.05};

/// An empty study folder (as a run leaves it before its first pair).
std::string emptyStudy(const std::string& name)
{
    const fs::path dir = sharedStudy().root / name;
    fs::remove_all(dir);
    fs::create_directories(dir / ".flyover");
    return dir.string();
}

/// Puts a file (or folder) of the shared study into `dir` the way a run does: written under a
/// temporary name, then renamed.
void land(const std::string& dir, const std::string& name)
{
    const fs::path src = fs::path(sharedStudy().study) / name, tmp = fs::path(dir) / ("." + name + ".tmp");
    fs::remove_all(tmp);
    fs::copy(src, tmp, fs::copy_options::recursive);
    fs::rename(tmp, fs::path(dir) / name);
}

/// Waits up to `seconds` for `done`; true when it came.
bool waitFor(const std::function<bool()>& done, double seconds = 20)
{
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
        if (done()) return true;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return done();
}

std::size_t missedRegions(const ViewStudy& s) { return s.studyJson()["missed_regions"].size(); }

} // namespace

TEST(ViewLive, TheStudyLockIsSeenWithoutBeingTaken)
{
    const std::string dir = emptyStudy("live-lock");
    EXPECT_FALSE(studyLockHeld(dir)) << "no lock file yet: no run";
    {
        StudyLock run(dir, false);
        EXPECT_TRUE(studyLockHeld(dir)) << "a run holds " << dir << "/.flyover/lock";
        // Looking did not take it: the holder still holds it, another run is refused.
        EXPECT_THROW(StudyLock(dir, false), StudyBusy);
    }
    EXPECT_FALSE(studyLockHeld(dir)) << "the run released its lock";
    for (int i = 0; i < 20; ++i) {
        EXPECT_FALSE(studyLockHeld(dir));
        StudyLock next(dir, false);  // never refused because of a look
    }
}

TEST(ViewLive, ProcLocksAreReadForGrantedFlocksOfTheFile)
{
    auto held = [](const std::string& text, long filePid) {
        std::istringstream in(text);
        return flockHeldIn(in, 0xfd, 0x01, 1234567, filePid);
    };
    EXPECT_TRUE(held("1: FLOCK  ADVISORY  WRITE 4242 fd:01:1234567 0 EOF\n", -1));
    EXPECT_FALSE(held("1: FLOCK  ADVISORY  WRITE 4242 fd:01:7654321 0 EOF\n", -1)) << "another file";
    EXPECT_FALSE(held("1: POSIX  ADVISORY  WRITE 4242 fd:01:1234567 0 EOF\n", -1)) << "not a flock";
    EXPECT_FALSE(held("1: -> FLOCK  ADVISORY  WRITE 4242 fd:01:1234567 0 EOF\n", -1)) << "only waiting for it";
    // An overlay file system: /proc/locks names another device; the holder's pid in the lock
    // file stands in for it, another pid does not.
    EXPECT_TRUE(held("2: FLOCK  ADVISORY  WRITE 4242 00:2a:1234567 0 EOF\n", 4242));
    EXPECT_FALSE(held("2: FLOCK  ADVISORY  WRITE 4242 00:2a:1234567 0 EOF\n", 99));
    EXPECT_FALSE(held("2: FLOCK  ADVISORY  WRITE 4242 00:2a:1234567 0 EOF\n", -1));
    EXPECT_TRUE(held("1: POSIX  ADVISORY  READ 7 08:02:11 0 EOF\n"
                     "2: -> FLOCK  ADVISORY  WRITE 9 fd:01:1234567 0 EOF\n"
                     "3: FLOCK  ADVISORY  WRITE 4242 fd:01:1234567 0 EOF\n",
                     -1));
    EXPECT_FALSE(held("", -1));
}

TEST(ViewLive, AStudyBeingComputedIsServedOnceItsSurfaceAndCenterlineAreWritten)
{
    const std::string dir = emptyStudy("live-computing");
    auto run = std::make_unique<StudyLock>(dir, false);
    LiveStudy live(dir, "", FAST);  // no throw: a run is computing it
    live.start();
    json st = live.status();
    EXPECT_EQ(st["revision"], 0);
    EXPECT_EQ(st["ready"], false);
    EXPECT_EQ(st["computing"], true);
    EXPECT_EQ(st["waiting_for"], json::array({"surface.ply", "centerline.json"})) << st.dump();
    EXPECT_FALSE(live.waitFirstLoad());
    try {
        live.current();
        FAIL() << "a study without its surface was served";
    } catch (const StudyNotReady& e) {
        EXPECT_NE(std::string(e.what()).find("being computed: waiting for surface.ply, centerline.json"),
                  std::string::npos)
            << e.what();
    }

    // The run's first files: the manifest, then the centerline; the surface still missing.
    land(dir, "manifest.json");
    land(dir, "centerline.json");
    ASSERT_TRUE(waitFor([&] { return live.status()["waiting_for"] == json::array({"surface.ply"}); }))
        << live.status().dump();
    EXPECT_EQ(live.status()["ready"], false);
    EXPECT_EQ(live.status()["stages"].size(), json(readJson(dir + "/manifest.json"))["stages"].size());

    land(dir, "surface.ply");
    ASSERT_TRUE(waitFor([&] { return live.status()["ready"] == true; })) << live.status().dump();
    int revision = 0;
    const auto first = live.current(&revision);
    EXPECT_EQ(revision, 1);
    EXPECT_FALSE(first->hasCt()) << "ct.vdb is not written yet";
    EXPECT_TRUE(first->sceneBuiltFast()) << "a run's first study is served on a fast-built scene";
    EXPECT_EQ(missedRegions(*first), 0u) << "no coverage yet";

    // At the next look the scene is rebuilt at Embree's default quality (nothing changed on disk).
    ASSERT_TRUE(waitFor([&] { return !live.current()->sceneBuiltFast(); })) << live.status().dump();
    int revision2 = 0;
    const auto second = live.current(&revision2);
    EXPECT_GT(revision2, revision);
    EXPECT_FALSE(second->sharesSurfaceWith(*first)) << "the fast-built scene is replaced, not reused";

    // The CT lands: a new revision with slices, the surface's scene taken over, not re-read.
    land(dir, "ct.vdb");
    ASSERT_TRUE(waitFor([&] { return live.current()->hasCt(); })) << live.status().dump();
    int revision3 = 0;
    const auto third = live.current(&revision3);
    EXPECT_GT(revision3, revision2);
    EXPECT_TRUE(third->sharesSurfaceWith(*second)) << "surface.ply did not change: its scene is reused";

    // Coverage lands: the missed regions appear.
    land(dir, "coverage");
    ViewStudy complete(sharedStudy().study);
    complete.load();
    const std::size_t want = missedRegions(complete);
    ASSERT_GT(want, 0u) << "the shared study has missed regions to show";
    ASSERT_TRUE(waitFor([&] { return missedRegions(*live.current()) == want; })) << live.status().dump();
    EXPECT_GT(live.revision(), revision3);
    EXPECT_TRUE(live.current()->sharesSurfaceWith(*third));

    // The run ends.
    run.reset();
    ASSERT_TRUE(waitFor([&] { return live.status()["computing"] == false; })) << live.status().dump();
    EXPECT_EQ(live.status()["error"], "");
    live.stop();
}

TEST(ViewLive, ARunsFlyOverIsServedBeforeItsCtGrid)
{
    const std::string dir = emptyStudy("live-ct-later");
    auto run = std::make_unique<StudyLock>(dir, false);
    LiveStudy live(dir, "", FAST);
    live.start();
    // Everything lands at once (as after a first pair): the surface is served first, without
    // the CT, and the CT follows in the next revision on the same scene.
    for (const char* f : {"manifest.json", "centerline.json", "surface.ply", "ct.vdb"}) land(dir, f);
    ASSERT_TRUE(waitFor([&] { return live.revision() >= 1; })) << live.status().dump();
    const auto first = live.current();
    EXPECT_FALSE(first->hasCt()) << "revision 1 leaves the CT grid for the next one";
    EXPECT_TRUE(first->sceneBuiltFast());
    ASSERT_TRUE(waitFor([&] { return live.revision() == 2; })) << live.status().dump();
    const auto second = live.current();
    EXPECT_TRUE(second->hasCt());
    EXPECT_FALSE(second->sceneBuiltFast()) << "revision 2 has the default-quality scene";
    EXPECT_FALSE(second->sharesSurfaceWith(*first));
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    EXPECT_EQ(live.revision(), 2) << "nothing changed since";
    live.stop();
}

TEST(ViewLive, ARewrittenSurfaceIsReadAgain)
{
    const std::string dir = copyStudy("live-rewrite");
    LiveStudy live(dir, "", FAST);
    live.start();
    ASSERT_TRUE(live.waitFirstLoad());
    const auto first = live.current();
    EXPECT_EQ(live.revision(), 1);
    EXPECT_FALSE(first->sceneBuiltFast()) << "a complete study is served on the default-quality scene";
    // A re-run replaces surface.ply (by rename): the new file is read, not the old scene kept.
    land(dir, "surface.ply");
    ASSERT_TRUE(waitFor([&] { return live.revision() == 2; })) << live.status().dump();
    EXPECT_FALSE(live.current()->sharesSurfaceWith(*first));
    // Nothing changes: no new revision.
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    EXPECT_EQ(live.revision(), 2);
}

TEST(ViewLive, ABrokenRewriteKeepsTheServedStudyAndSaysWhy)
{
    const std::string dir = copyStudy("live-broken");
    LiveStudy live(dir, "", FAST);
    live.start();
    ASSERT_TRUE(live.waitFirstLoad());
    const fs::path tmp = fs::path(dir) / ".centerline.tmp";
    std::ofstream(tmp) << "{\"points\": [";
    fs::rename(tmp, fs::path(dir) / "centerline.json");
    ASSERT_TRUE(waitFor([&] { return !live.status()["error"].get<std::string>().empty(); })) << live.status().dump();
    EXPECT_NE(live.status()["error"].get<std::string>().find("centerline.json"), std::string::npos)
        << live.status().dump();
    EXPECT_EQ(live.revision(), 1);
    EXPECT_NO_THROW(live.current()->studyJson()) << "the study served before stays served";
    land(dir, "centerline.json");  // repaired
    ASSERT_TRUE(waitFor([&] { return live.revision() == 2; })) << live.status().dump();
    EXPECT_EQ(live.status()["error"], "");
}

TEST(ViewLive, ARunThatEndsWithoutTheSurfaceIsReported)
{
    const std::string dir = emptyStudy("live-failed");
    auto run = std::make_unique<StudyLock>(dir, false);
    LiveStudy live(dir, "", FAST);
    live.start();
    land(dir, "centerline.json");
    run.reset();  // the run failed before its mesh
    ASSERT_TRUE(waitFor([&] { return live.status()["computing"] == false; })) << live.status().dump();
    const json st = live.status();
    EXPECT_EQ(st["ready"], false);
    EXPECT_NE(st["error"].get<std::string>().find("lacks surface.ply and no flyover run is computing it"),
              std::string::npos)
        << st.dump();
}

TEST(ViewLive, WithoutARunAStudyLackingItsSurfaceIsRefusedAtOnce)
{
    const std::string dir = emptyStudy("live-norun");
    land(dir, "centerline.json");
    try {
        LiveStudy live(dir, "", FAST);
        FAIL() << "a study without surface.ply and no run computing it was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("lacks surface.ply"), std::string::npos) << e.what();
    }
}

TEST(ViewLive, TheServerAnswers503WhileComputingAndTheStudyOnceWritten)
{
    const std::string dir = emptyStudy("live-http");
    auto run = std::make_unique<StudyLock>(dir, false);
    RunningServer s(dir, "", FAST);
    auto c = s.client();
    auto st = c->Get("/api/status");
    ASSERT_TRUE(st);
    EXPECT_EQ(st->status, 200);
    EXPECT_EQ(json::parse(st->body)["computing"], true) << st->body;
    for (const char* path : {"/api/study", "/api/pair?arc_mm=10", "/api/overview"}) {
        auto r = c->Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_EQ(r->status, 503) << path << ": " << r->body;
        EXPECT_NE(json::parse(r->body)["error"].get<std::string>().find("being computed"), std::string::npos) << r->body;
    }
    auto noToken = s.client(false)->Get("/api/status");
    ASSERT_TRUE(noToken);
    EXPECT_EQ(noToken->status, 403) << "the status needs the token too";
    for (const char* f : {"manifest.json", "centerline.json", "surface.ply"}) land(dir, f);
    ASSERT_TRUE(waitFor([&] {
        auto r = c->Get("/api/status");
        return r && json::parse(r->body)["ready"] == true;
    }));
    auto study = c->Get("/api/study");
    ASSERT_TRUE(study);
    ASSERT_EQ(study->status, 200) << study->body;
    EXPECT_GE(json::parse(study->body)["revision"].get<int>(), 1);
    auto pair = c->Get("/api/pair?arc_mm=10&px=64");
    ASSERT_TRUE(pair);
    EXPECT_EQ(pair->status, 200);
    EXPECT_EQ(pair->get_header_value("Content-Type"), "image/jpeg");
}

} // namespace flyover::test
