// The viewer's findings API on a copy of the phantom study with a hand-written
// polyps/candidates.json: review, edit, a finding by hand, delete; hostile requests answered
// 4xx with one line; findings.json kept across restarts and re-runs, a corrupt one never
// overwritten.

#include "colon/findings.h"
#include "view_fixture.h"

#include <fstream>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace flyover;
using namespace flyover::test;

namespace {

/// A copy of the shared study with candidates c1, c2 at the truth's first two polyps.
std::string studyWithCandidates(const std::string& name)
{
    const std::string dir = copyStudy(name);
    const auto& truth = sharedStudy().truth;
    json list = json::array();
    for (std::size_t k = 0; k < 2 && k < truth.polyps.size(); ++k) {
        const auto& p = truth.polyps[k];
        list.push_back(json{{"id", "c" + std::to_string(k + 1)},
                            {"centroid_mm", vec3Json(p.centerMm)},
                            {"size_mm", 2 * p.radiusMm},
                            {"height_mm", p.radiusMm},
                            {"volume_mm3", 2.1 * p.radiusMm * p.radiusMm * p.radiusMm},
                            {"morphology", "sessile"},
                            {"arc_mm", 100.0 * double(k + 1)},
                            {"segment", "sigmoid"},
                            {"score", 0.9 - 0.2 * double(k)},
                            {"pose", nullptr}});
    }
    fs::create_directories(fs::path(dir) / "polyps");
    writeJson(dir + "/polyps/candidates.json", json{{"schema", "flyover.polyps/1"}, {"candidates", list}});
    return dir;
}

json post(httplib::Client& c, const RunningServer& s, const std::string& path, const std::string& body, int expected)
{
    auto r = c.Post(path, httplib::Headers{{"Origin", s.origin()}}, body, "application/json");
    EXPECT_TRUE(r);
    if (!r) return json();
    EXPECT_EQ(r->status, expected) << path << " " << body << " -> " << r->body;
    const json j = json::parse(r->body, nullptr, false);
    if (r->status >= 400) {
        EXPECT_TRUE(j.is_object() && j.contains("error")) << r->body;
        EXPECT_EQ(r->body.find('\n'), std::string::npos);
    }
    return j;
}

} // namespace

TEST(ViewFindings, ReviewEditAddByHandAndDelete)
{
    const std::string dir = studyWithCandidates("findings");
    {
        RunningServer s(dir);
        auto c = s.client();
        auto list = c->Get("/api/findings");
        ASSERT_TRUE(list);
        ASSERT_EQ(list->status, 200) << list->body;
        json j = json::parse(list->body);
        ASSERT_EQ(j["candidates"].size(), 2u);
        EXPECT_EQ(j["candidates"][0]["id"], "c1");
        EXPECT_EQ(j["candidates"][0]["status"], "unreviewed");
        EXPECT_TRUE(j["findings"].empty());

        json a = post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"accepted","size_mm":11.5})", 201);
        EXPECT_EQ(a["finding"]["candidate_id"], "c1");
        EXPECT_DOUBLE_EQ(a["finding"]["size_mm"].get<double>(), 11.5);
        // reviewing again updates the same finding
        json again = post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"rejected"})", 200);
        EXPECT_EQ(again["finding"]["id"], a["finding"]["id"]);
        EXPECT_DOUBLE_EQ(again["finding"]["size_mm"].get<double>(), 11.5);
        post(*c, s, "/api/findings/edit",
             json{{"id", a["finding"]["id"]}, {"status", "accepted"}, {"size_mm", 12.0}, {"note", "fold"}}.dump(), 200);
        post(*c, s, "/api/findings/review", R"({"candidate_id":"c2","status":"rejected"})", 201);

        const Vec3d p = s.study().centerline().points[150].positionMm + Vec3d{2, 0, 0};
        json h = post(*c, s, "/api/findings/hand",
                      json{{"position_mm", vec3Json(p)}, {"size_mm", 7}, {"morphology", "flat"}}.dump(), 201);
        EXPECT_EQ(h["finding"]["source"], "hand");
        EXPECT_EQ(h["finding"]["status"], "accepted");
        EXPECT_NEAR(h["finding"]["arc_mm"].get<double>(), 150 * s.study().centerline().stepMm, 5.0);
        EXPECT_EQ(h["finding"]["segment"], s.study().centerline().segment.at(std::size_t(
                                               std::lround(h["finding"]["arc_mm"].get<double>() / s.study().centerline().stepMm))));

        auto del = c->Delete("/api/findings?id=" + h["finding"]["id"].get<std::string>(), httplib::Headers{{"Origin", s.origin()}});
        ASSERT_TRUE(del);
        EXPECT_EQ(del->status, 200) << del->body;
        auto delAgain = c->Delete("/api/findings?id=" + h["finding"]["id"].get<std::string>(), httplib::Headers{{"Origin", s.origin()}});
        EXPECT_EQ(delAgain->status, 404);
    }
    // kept across a restart
    const auto onDisk = readFindings(dir + "/findings.json");
    ASSERT_EQ(onDisk.size(), 2u);
    EXPECT_EQ(onDisk[0].status, "accepted");
    EXPECT_DOUBLE_EQ(onDisk[0].sizeMm, 12.0);
    EXPECT_EQ(onDisk[0].note, "fold");
    RunningServer s(dir);
    auto c = s.client();
    const json j = json::parse(c->Get("/api/findings")->body);
    EXPECT_EQ(j["findings"].size(), 2u);
    EXPECT_EQ(j["candidates"][1]["status"], "rejected");
}

TEST(ViewFindings, HostileRequestsAreRefusedWithOneLine)
{
    const std::string dir = studyWithCandidates("findings-hostile");
    RunningServer s(dir);
    auto c = s.client();
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c9","status":"accepted"})", 404);
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"maybe"})", 400);
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1"})", 400);
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"accepted","size_mm":1e9})", 422);
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"accepted","colour":"red"})", 400);
    post(*c, s, "/api/findings/review", "[1,2", 400);
    post(*c, s, "/api/findings/review", json{{"candidate_id", "c1"}, {"status", "accepted"}, {"note", std::string(3000, 'x')}}.dump(), 422);
    post(*c, s, "/api/findings/edit", R"({"id":"f77","size_mm":5})", 404);
    post(*c, s, "/api/findings/hand", R"({"position_mm":[1,2],"size_mm":5})", 400);
    post(*c, s, "/api/findings/hand", R"({"position_mm":[1e4,0,0],"size_mm":5})", 422);
    post(*c, s, "/api/findings/hand", R"({"position_mm":[0,0,0]})", 400);
    post(*c, s, "/api/findings/nothing", "{}", 404);
    // too large a body, the wrong method, no Origin
    auto big = c->Post("/api/findings/hand", httplib::Headers{{"Origin", s.origin()}}, std::string(70000, ' '), "application/json");
    ASSERT_TRUE(big);
    EXPECT_EQ(big->status, 413);
    auto get = c->Get("/api/findings/review");
    EXPECT_EQ(get->status, 405);
    auto noOrigin = c->Post("/api/findings/review", R"({"candidate_id":"c1","status":"accepted"})", "application/json");
    EXPECT_EQ(noOrigin->status, 403);
    auto unknown = c->Get("/api/findings?colour=red");
    EXPECT_EQ(unknown->status, 400);
    EXPECT_FALSE(fs::exists(dir + "/findings.json"));  // nothing was accepted
}

TEST(ViewFindings, ACorruptFileIsReportedNotOverwritten)
{
    const std::string dir = studyWithCandidates("findings-corrupt");
    const std::string text = R"({"schema": "flyover.findings/1", "findings": [{"id": "f1"}]})";
    { std::ofstream(dir + "/findings.json", std::ios::binary) << text; }
    RunningServer s(dir);
    auto c = s.client();
    const json j = json::parse(c->Get("/api/findings")->body);
    EXPECT_NE(j["error"].get<std::string>().find("findings.json"), std::string::npos) << j.dump();
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"accepted"})", 409);
    std::ifstream in(dir + "/findings.json", std::ios::binary);
    EXPECT_EQ(std::string((std::istreambuf_iterator<char>(in)), {}), text);
}

TEST(ViewFindings, SurviveARerunOfThePipeline)
{
    const SharedStudy& shared = sharedStudy();
    const std::string file = shared.study + "/findings.json";
    Finding f;
    f.id = "f1";
    f.source = "hand";
    f.status = "accepted";
    f.sizeMm = 8;
    f.segment = "cecum";
    f.morphology = "flat";
    writeFindings(file, {f});
    RunOptions o = shared.options;
    o.forceStage = "render";
    runPipeline(o);
    const auto back = readFindings(file);
    ASSERT_EQ(back.size(), 1u);
    EXPECT_DOUBLE_EQ(back[0].sizeMm, 8.0);
    fs::remove(file);
}

namespace {

/// Pixels within 14 of `rgb` on every channel in the square of half-side `reach` around (cx, cy).
int colourNear(const RgbImage& img, const std::array<int, 3>& rgb, double cx, double cy, double reach)
{
    int n = 0;
    for (int y = std::max(0, int(cy - reach)); y < std::min(img.height, int(cy + reach) + 1); ++y)
        for (int x = std::max(0, int(cx - reach)); x < std::min(img.width, int(cx + reach) + 1); ++x) {
            const uint8_t* p = &img.rgb[(std::size_t(y) * std::size_t(img.width) + std::size_t(x)) * 3];
            if (std::abs(p[0] - rgb[0]) <= 14 && std::abs(p[1] - rgb[1]) <= 14 && std::abs(p[2] - rgb[2]) <= 14) ++n;
        }
    return n;
}

} // namespace

TEST(ViewFindings, TheOverviewRingsCandidatesAndFindingsByStatus)
{
    const std::string dir = studyWithCandidates("overview_marks");
    RunningServer s(dir);
    auto c = s.client();
    const int px = 400;
    auto get = [&](const std::string& q) {
        auto r = c->Get(("/api/overview?px=" + std::to_string(px) + q).c_str());
        EXPECT_TRUE(r && r->status == 200) << q << " -> " << (r ? r->body : "no answer");
        return r && r->status == 200 ? decodePng(r->body) : RgbImage{};
    };
    const Camera cam = s.study().overviewCamera();
    auto at = [&](const Vec3d& p) {
        const Vec3d v = p - cam.position;
        const double z = dot(v, cam.forward), t = std::tan(0.5 * cam.fovDeg * 3.14159265358979 / 180.0);
        return std::array<double, 2>{(dot(v, cam.right) / z / t + 1) * 0.5 * px, (1 - dot(v, cam.up) / z / t) * 0.5 * px};
    };
    const auto& truth = sharedStudy().truth;
    const auto p1 = at(truth.polyps[0].centerMm), p2 = at(truth.polyps[1].centerMm);
    const std::array<int, 3> cyan{74, 209, 255}, green{107, 214, 139}, orange{255, 159, 67};
    const double reach = 30;

    const RgbImage plain = get(""), marked = get("&findings=1");
    ASSERT_EQ(marked.width, px);
    EXPECT_EQ(colourNear(plain, cyan, p1[0], p1[1], reach), 0) << "without findings=1 the overview is unmarked";
    EXPECT_GT(colourNear(marked, cyan, p1[0], p1[1], reach), 10) << "candidate c1 ringed cyan at its projection";
    EXPECT_GT(colourNear(marked, cyan, p2[0], p2[1], reach), 10) << "candidate c2 ringed cyan at its projection";

    post(*c, s, "/api/findings/review", R"({"candidate_id":"c1","status":"accepted","size_mm":11.5})", 201);
    post(*c, s, "/api/findings/review", R"({"candidate_id":"c2","status":"rejected"})", 201);
    const Vec3d hp = s.study().centerline().points[s.study().centerline().points.size() / 2].positionMm;
    post(*c, s, "/api/findings/hand", json{{"position_mm", vec3Json(hp)}, {"size_mm", 8}, {"morphology", "sessile"}}.dump(), 201);
    const RgbImage reviewed = get("&findings=1");
    EXPECT_GT(colourNear(reviewed, green, p1[0], p1[1], reach), 10) << "accepted c1 ringed green";
    EXPECT_EQ(colourNear(reviewed, cyan, p1[0], p1[1], reach), 0) << "accepted c1 no longer cyan";
    EXPECT_EQ(colourNear(reviewed, cyan, p2[0], p2[1], reach), 0) << "rejected c2 not ringed";
    const auto h = at(hp);
    EXPECT_GT(colourNear(reviewed, orange, h[0], h[1], reach), colourNear(plain, orange, h[0], h[1], reach) + 10)
        << "the hand finding ringed orange";

    auto bad = c->Get("/api/overview?findings=2");
    ASSERT_TRUE(bad);
    EXPECT_EQ(bad->status, 422) << bad->body;
}
