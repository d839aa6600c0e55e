// The viewer's HTTP API on a small phantom study: pairs (size, formats, the very pixels of the
// render stage's frames), pick, locate round trips on every truth polyp, slices and their
// pixel <-> LPS mapping, the overview, bookmarks across a restart, screenshots.

#include "view_fixture.h"

#include "volume/error.h"

#include <cmath>
#include <fstream>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace flyover;
using namespace flyover::test;

namespace {

std::string q(double v)
{
    std::ostringstream o;
    o.precision(17);
    o << v;
    return o.str();
}

Vec3d vec(const json& a) { return Vec3d{a[0].get<double>(), a[1].get<double>(), a[2].get<double>()}; }

class ViewApi : public ::testing::Test {
protected:
    static void SetUpTestSuite() { sServer = new RunningServer(sharedStudy().study); }
    static void TearDownTestSuite()
    {
        delete sServer;
        sServer = nullptr;
    }
    static inline RunningServer* sServer = nullptr;
};

} // namespace

TEST_F(ViewApi, StudyDescribesPathCtAndMissedRegions)
{
    auto c = sServer->client();
    auto r = c->Get("/api/study");
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
    const json j = json::parse(r->body);
    EXPECT_EQ(j["world_frame"], "LPS");
    const Centerline& cl = sServer->study().centerline();
    EXPECT_EQ(j["centerline"].size(), cl.points.size());
    EXPECT_EQ(j["bridged"].size(), cl.points.size());
    EXPECT_NEAR(j["arc_max_mm"].get<double>(), double(cl.points.size() - 1) * cl.stepMm, 1e-9);
    EXPECT_EQ(j["default_px"], STUDY_PX);
    EXPECT_TRUE(j["has_ct"].get<bool>());
    const Vec3d lo = vec(j["ct"]["bounds_mm"][0]), hi = vec(j["ct"]["bounds_mm"][1]);
    // Every centerline point lies inside the CT's bounds.
    for (const auto& p : cl.points) {
        EXPECT_GE(p.positionMm.x, lo.x);
        EXPECT_LE(p.positionMm.z, hi.z);
    }
    EXPECT_TRUE(j["missed_regions"].is_array());
    EXPECT_TRUE(j["polyps"].empty()) << "the server never knows the truth";
    const json cov = readJson(sharedStudy().study + "/coverage/coverage.json");
    EXPECT_EQ(j["missed_regions"].size(), cov["flyover"]["both_cameras"]["missed_regions"].size());
}

TEST_F(ViewApi, PairHasTwoViewsSideBySideInJpegAndPng)
{
    auto c = sServer->client();
    for (const int px : {64, 200}) {
        auto png = c->Get(("/api/pair?arc_mm=50&px=" + std::to_string(px) + "&format=png").c_str());
        ASSERT_TRUE(png);
        ASSERT_EQ(png->status, 200) << png->body;
        EXPECT_EQ(png->get_header_value("Content-Type"), "image/png");
        const RgbImage img = decodePng(png->body);
        EXPECT_EQ(img.height, px);
        EXPECT_EQ(img.width, 2 * px + 4) << "two views and the 4 px separator of sideBySide";
        auto jpg = c->Get(("/api/pair?arc_mm=50&px=" + std::to_string(px)).c_str());
        ASSERT_TRUE(jpg);
        ASSERT_EQ(jpg->status, 200) << jpg->body;
        EXPECT_EQ(jpg->get_header_value("Content-Type"), "image/jpeg");
        ASSERT_GT(jpg->body.size(), 4u);
        EXPECT_EQ(uint8_t(jpg->body[0]), 0xFF);
        EXPECT_EQ(uint8_t(jpg->body[1]), 0xD8);
        const json pose = json::parse(jpg->get_header_value("X-Flyover-Pose"));
        EXPECT_NEAR(pose["arc_mm"].get<double>(), 50.0, 0.5 * sServer->study().stepMm());
        EXPECT_EQ(pose["cameras"].size(), 2u);
    }
}

TEST_F(ViewApi, SamePoseGivesTheRenderStagesFramePixels)
{
    const fs::path frames = fs::path(sharedStudy().study) / "frames";
    const json poses = readJson((frames / "poses.json").string());
    ASSERT_GE(poses["frames"].size(), 2u);
    auto c = sServer->client();
    for (const auto& f : poses["frames"]) {
        const RgbImage want = readPng((frames / f["file"].get<std::string>()).string());
        auto r = c->Get(("/api/pair?format=png&arc_mm=" + q(f["arc_mm"].get<double>())).c_str());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << r->body;
        const RgbImage got = decodePng(r->body);
        ASSERT_EQ(got.width, want.width);
        ASSERT_EQ(got.height, want.height);
        std::size_t differing = 0;
        for (std::size_t i = 0; i < want.rgb.size(); ++i) differing += got.rgb[i] != want.rgb[i];
        EXPECT_EQ(differing, 0u) << f["file"] << ": bytes differing from the render stage's frame";
        // The same cameras as poses.json.
        const json pose = json::parse(r->get_header_value("X-Flyover-Pose"));
        for (int k = 0; k < 2; ++k)
            EXPECT_LT(distance(vec(pose["cameras"][k]["position_mm"]), vec(f["cameras"][k]["position_mm"])), 1e-9);
    }
    // Another roll is another picture.
    const json& f = poses["frames"][1];
    auto rolled = c->Get(("/api/pair?format=png&roll_deg=90&arc_mm=" + q(f["arc_mm"].get<double>())).c_str());
    ASSERT_TRUE(rolled);
    EXPECT_NE(decodePng(rolled->body).rgb, readPng((frames / f["file"].get<std::string>()).string()).rgb);
}

TEST_F(ViewApi, PickOnTheCentrePixelHitsTheWall)
{
    auto c = sServer->client();
    const double arc = 0.5 * sServer->study().arcMaxMm();
    const std::size_t i = sServer->study().indexOfArc(arc);
    const CenterlinePoint& p = sServer->study().centerline().points[i];
    for (int view = 0; view < 2; ++view) {
        auto r = c->Get(("/api/pick?arc_mm=" + q(arc) + "&px=256&view=" + std::to_string(view) + "&x=128&y=128").c_str());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << r->body;
        const json j = json::parse(r->body);
        ASSERT_TRUE(j["hit"].get<bool>()) << r->body;
        const Vec3d hit = vec(j["point_mm"]);
        // The centre ray goes through the centerline point: the hit is beyond it, on the wall,
        // about D(p) away (a fold or a bulge may be nearer or farther).
        const double d = distance(hit, p.positionMm);
        EXPECT_GT(d, 0.3 * p.radiusMm);
        EXPECT_LT(d, 3.0 * p.radiusMm + 5.0);
        const Camera cam = sServer->study().cameras(ViewPose{arc, sServer->study().renderParams().rollDeg, "right",
                                                           "flyover", -1, 256})[std::size_t(view)];
        EXPECT_NEAR(j["distance_mm"].get<double>(), distance(hit, cam.position), 1e-6);
        // On the camera's axis and beyond the centerline point.
        EXPECT_GT(dot(hit - cam.position, cam.forward), dot(p.positionMm - cam.position, cam.forward));
        EXPECT_LT(length(cross(normalize(hit - cam.position), cam.forward)), 0.02);
    }
}

TEST_F(ViewApi, LocateThenPickFindsEveryTruthPolyp)
{
    auto c = sServer->client();
    const auto& polyps = sharedStudy().truth.polyps;
    ASSERT_FALSE(polyps.empty());
    for (const auto& polyp : polyps) {
        const Vec3d m = polyp.centerMm;
        auto r = c->Get(("/api/locate?x_mm=" + q(m.x) + "&y_mm=" + q(m.y) + "&z_mm=" + q(m.z)).c_str());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << r->body;
        const json l = json::parse(r->body);
        const int px = l["px"];
        EXPECT_GE(l["x"].get<double>(), 0.0);
        EXPECT_LE(l["x"].get<double>(), px);
        EXPECT_GE(l["y"].get<double>(), 0.0);
        EXPECT_LE(l["y"].get<double>(), px);
        auto pk = c->Get(("/api/pick?arc_mm=" + q(l["arc_mm"]) + "&roll_deg=" + q(l["roll_deg"]) + "&direction=" +
                          l["direction"].get<std::string>() + "&px=" + std::to_string(px) +
                          "&view=" + std::to_string(l["view"].get<int>()) + "&x=" + q(l["x"]) + "&y=" + q(l["y"]))
                             .c_str());
        ASSERT_TRUE(pk);
        ASSERT_EQ(pk->status, 200) << pk->body;
        const json h = json::parse(pk->body);
        ASSERT_TRUE(h["hit"].get<bool>()) << "polyp at arc " << polyp.arcMm;
        // The roll puts the point on the view's horizontal midline (the image's vertical axis is
        // the lateral one); along the tangent it may be off-centre by its arc offset.
        EXPECT_NEAR(l["y"].get<double>(), 0.5 * px, 1e-6 * px) << "polyp at arc " << polyp.arcMm;
        // On the polyp's surface: within 1 mm plus half a voxel, because the small phantom's 2.5 mm
        // voxels flatten its 3-4 mm polyps in the reconstructed surface.
        const double d = distance(vec(h["point_mm"]), m);
        EXPECT_NEAR(d, polyp.radiusMm, 1.0 + 0.5 * 2.5) << "polyp at arc " << polyp.arcMm << " radius "
                                                        << polyp.radiusMm << ": the picked point is not on its surface";
    }
}

TEST_F(ViewApi, SlicesHaveTheirSizeAndAMappingThatRoundTrips)
{
    auto c = sServer->client();
    const Centerline& cl = sServer->study().centerline();
    const Vec3d p = cl.points[cl.points.size() / 3].positionMm;  // inside the lumen: air
    for (const std::string plane : {"axial", "coronal", "sagittal"}) {
        auto r = c->Get(("/api/slice?plane=" + plane + "&x_mm=" + q(p.x) + "&y_mm=" + q(p.y) + "&z_mm=" + q(p.z) +
                         "&window=1500&level=-300")
                            .c_str());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, 200) << r->body;
        const json g = json::parse(r->get_header_value("X-Flyover-Slice"));
        const RgbImage img = decodePng(r->body);
        EXPECT_EQ(img.width, g["width"].get<int>()) << plane;
        EXPECT_EQ(img.height, g["height"].get<int>()) << plane;
        const Vec3d o = vec(g["origin_mm"]), rd = vec(g["row_dir"]), cd = vec(g["col_dir"]);
        const double pix = g["pixel_mm"];
        // Radiological display: patient's right (-x in LPS) on the image's left; superior up.
        if (plane != "sagittal") {
            EXPECT_GT(cd.x, 0.99) << plane;
        }
        if (plane != "axial") {
            EXPECT_LT(rd.z, -0.99) << plane;
        }
        if (plane == "axial") {
            EXPECT_GT(rd.y, 0.99) << "anterior up";
        }
        if (plane == "sagittal") {
            EXPECT_GT(cd.y, 0.99) << "anterior on the left";
        }
        // World -> pixel -> world.
        const double col = dot(p - o, cd) / pix, row = dot(p - o, rd) / pix;
        const Vec3d back = o + cd * (col * pix) + rd * (row * pix);
        EXPECT_LT(distance(back, p), 1e-6) << plane << ": the point is not in the slice's plane";
        // The centerline point is in the lumen: air, dark at W 1500 / L -300 (-1000 HU -> 8).
        const int ci = int(std::lround(col)), ri = int(std::lround(row));
        ASSERT_TRUE(ci >= 0 && ci < img.width && ri >= 0 && ri < img.height) << plane;
        EXPECT_LT(img.rgb[3 * (std::size_t(ri) * std::size_t(img.width) + std::size_t(ci))], 60) << plane;
        // And the slice shows more than air: the body is brighter somewhere.
        EXPECT_GT(*std::max_element(img.rgb.begin(), img.rgb.end()), 150) << plane;
    }
    auto bad = c->Get("/api/slice?plane=oblique&x_mm=0&y_mm=0&z_mm=0");
    ASSERT_TRUE(bad);
    EXPECT_EQ(bad->status, 400);
    auto outside = c->Get(("/api/slice?plane=axial&x_mm=0&y_mm=0&z_mm=" + q(p.z + 1e5)).c_str());
    ASSERT_TRUE(outside);
    EXPECT_EQ(outside->status, 422);
}

TEST_F(ViewApi, OverviewMatchesTheStudysAndItsPickJumpsToThePath)
{
    auto c = sServer->client();
    auto r = c->Get("/api/overview");
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
    const RgbImage got = decodePng(r->body);
    const RgbImage want = readPng(sharedStudy().study + "/overview.png");
    ASSERT_EQ(got.width, want.width);
    EXPECT_EQ(got.rgb, want.rgb) << "the unmarked overview is the render stage's overview.png";
    auto marked = c->Get("/api/overview?marker_mm=100&px=300");
    ASSERT_TRUE(marked);
    ASSERT_EQ(marked->status, 200);
    EXPECT_EQ(decodePng(marked->body).width, 300);
    // The projection of a centerline point, picked, gives an arc near it.
    const Camera cam = sServer->study().overviewCamera();
    const Centerline& cl = sServer->study().centerline();
    const std::size_t i = cl.points.size() / 2;
    const Vec3d v = cl.points[i].positionMm - cam.position;
    const double z = dot(v, cam.forward), t = std::tan(0.5 * cam.fovDeg * 3.14159265358979 / 180.0);
    const int px = 400;
    const double x = (dot(v, cam.right) / z / t + 1) * 0.5 * px, y = (1 - dot(v, cam.up) / z / t) * 0.5 * px;
    auto pk = c->Get(("/api/overview/pick?px=400&x=" + q(x) + "&y=" + q(y)).c_str());
    ASSERT_TRUE(pk);
    ASSERT_EQ(pk->status, 200) << pk->body;
    const json j = json::parse(pk->body);
    ASSERT_TRUE(j["hit"].get<bool>());
    // The wall seen there belongs to this stretch (or one lying in front of it along the view).
    const std::size_t k = sServer->study().nearestIndex(vec(j["point_mm"]));
    EXPECT_NEAR(j["arc_mm"].get<double>(), double(k) * cl.stepMm, 1e-9);
    auto corner = c->Get("/api/overview/pick?px=400&x=0.5&y=0.5");
    ASSERT_TRUE(corner);
    EXPECT_FALSE(json::parse(corner->body)["hit"].get<bool>()) << "the overview's corner is background";
}

TEST(ViewBookmarks, SurviveARestartAndDelete)
{
    const std::string dir = copyStudy("bookmarks");
    std::string id;
    {
        RunningServer s(dir);
        auto c = s.client();
        httplib::Headers h{{"Origin", s.origin()}};
        auto add = c->Post("/api/bookmarks", h,
                           R"({"note":"polyp?","arc_mm":120.0,"roll_deg":30,"direction":"left","mode":"flyover",
                               "clip_offset_fraction":0.4})",
                           "application/json");
        ASSERT_TRUE(add);
        ASSERT_EQ(add->status, 201) << add->body;
        const json b = json::parse(add->body);
        id = b["id"];
        EXPECT_EQ(b["note"], "polyp?");
        EXPECT_EQ(b["direction"], "left");
        EXPECT_TRUE(b.contains("created"));
        auto second = c->Post("/api/bookmarks", h, R"({"note":"two","arc_mm":10})", "application/json");
        ASSERT_EQ(second->status, 201) << second->body;
        auto bad = c->Post("/api/bookmarks", h, R"({"note":"x","arc_mm":1e9})", "application/json");
        ASSERT_TRUE(bad);
        EXPECT_EQ(bad->status, 422) << bad->body;
        auto unknown = c->Post("/api/bookmarks", h, R"({"arc_mm":1,"colour":"red"})", "application/json");
        EXPECT_EQ(unknown->status, 400) << unknown->body;
        auto notJson = c->Post("/api/bookmarks", h, "{arc_mm", "application/json");
        EXPECT_EQ(notJson->status, 400);
    }
    const json onDisk = readJson(dir + "/bookmarks.json");
    EXPECT_EQ(onDisk["bookmarks"].size(), 2u);
    {
        RunningServer s(dir);
        auto c = s.client();
        auto list = c->Get("/api/bookmarks");
        ASSERT_EQ(list->status, 200);
        const json l = json::parse(list->body)["bookmarks"];
        ASSERT_EQ(l.size(), 2u);
        EXPECT_EQ(l[0]["id"], id);
        EXPECT_DOUBLE_EQ(l[0]["arc_mm"].get<double>(), 120.0);
        EXPECT_DOUBLE_EQ(l[0]["roll_deg"].get<double>(), 30.0);
        EXPECT_DOUBLE_EQ(l[0]["clip_offset_fraction"].get<double>(), 0.4);
        httplib::Headers h{{"Origin", s.origin()}};
        auto del = c->Delete(("/api/bookmarks?id=" + id).c_str(), h);
        ASSERT_EQ(del->status, 200) << del->body;
        auto again = c->Delete(("/api/bookmarks?id=" + id).c_str(), h);
        EXPECT_EQ(again->status, 404);
        EXPECT_EQ(json::parse(c->Get("/api/bookmarks")->body)["bookmarks"].size(), 1u);
        // A new one after the restart gets a fresh id.
        auto add = c->Post("/api/bookmarks", h, R"({"arc_mm":5})", "application/json");
        ASSERT_EQ(add->status, 201);
        EXPECT_NE(json::parse(add->body)["id"], id);
    }
    EXPECT_EQ(readJson(dir + "/bookmarks.json")["bookmarks"].size(), 2u);
}

TEST(ViewBookmarks, SurviveARerunOfThePipeline)
{
    const SharedStudy& shared = sharedStudy();
    const std::string file = shared.study + "/bookmarks.json";
    {
        BookmarkStore store(file);
        store.add(json{{"note", "kept"}, {"arc_mm", 3.0}});
    }
    RunOptions o = shared.options;
    o.forceStage = "render";  // rewrites frames/, overviews/, coverage/ around the file
    runPipeline(o);
    const json j = readJson(file);
    ASSERT_EQ(j["bookmarks"].size(), 1u);
    EXPECT_EQ(j["bookmarks"][0]["note"], "kept");
    fs::remove(file);
}

TEST(ViewBookmarks, ACorruptFileIsReportedNotOverwritten)
{
    const std::string dir = copyStudy("bookmarks-corrupt");
    {
        std::ofstream(dir + "/bookmarks.json") << "[1, 2";
    }
    LiveStudy study(dir, "");
    try {
        ViewServer server(study, ViewServerOptions{});
        FAIL() << "a corrupt bookmarks.json was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("bookmarks.json"), std::string::npos) << e.what();
    }
    std::ifstream in(dir + "/bookmarks.json");
    EXPECT_EQ(std::string((std::istreambuf_iterator<char>(in)), {}), "[1, 2");
}

TEST(ViewScreenshot, WritesThePairAndItsPoseAndServesThem)
{
    const std::string dir = copyStudy("screenshot");
    RunningServer s(dir);
    auto c = s.client();
    auto r = c->Post("/api/screenshot", httplib::Headers{{"Origin", s.origin()}},
                     R"({"arc_mm":80,"roll_deg":-45,"direction":"right","mode":"flyover","px":96})", "application/json");
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 201) << r->body;
    const json j = json::parse(r->body);
    const fs::path png = fs::path(dir) / j["file"].get<std::string>();
    const fs::path pose = fs::path(dir) / j["pose_file"].get<std::string>();
    ASSERT_TRUE(fs::exists(png));
    ASSERT_TRUE(fs::exists(pose));
    const RgbImage img = readPng(png.string());
    EXPECT_EQ(img.height, 96);
    EXPECT_EQ(img.width, 2 * 96 + 4);
    const json pj = readJson(pose.string());
    EXPECT_DOUBLE_EQ(pj["roll_deg"].get<double>(), -45.0);
    EXPECT_EQ(pj["world_frame"], "LPS");
    // The same pose over /api/pair gives the same pixels.
    auto pair = c->Get("/api/pair?arc_mm=80&roll_deg=-45&px=96&format=png");
    EXPECT_EQ(decodePng(pair->body).rgb, img.rgb);
    auto dl = c->Get(j["url"].get<std::string>().c_str());
    ASSERT_TRUE(dl);
    ASSERT_EQ(dl->status, 200);
    EXPECT_NE(dl->get_header_value("Content-Disposition").find("attachment"), std::string::npos);
    std::ifstream in(png, std::ios::binary);
    EXPECT_EQ(dl->body, std::string((std::istreambuf_iterator<char>(in)), {}));
    auto missing = c->Get("/api/screenshots/shot_nothing.png");
    EXPECT_EQ(missing->status, 404);
    auto get = c->Get("/api/screenshot");
    EXPECT_EQ(get->status, 405);
}
