// The viewer's defences: token, Host (DNS rebinding), Origin on state changes, path traversal,
// strict parameters, body size, and a few hundred random requests.

#include "view_fixture.h"

#include <random>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace flyover;
using namespace flyover::test;

namespace {

/// A page folder with index.html and one script, next to a secret file that must never be served.
struct AssetFolder {
    fs::path root, web;
    AssetFolder()
    {
        root = sharedStudy().root / "assets-test";
        web = root / "web";
        fs::create_directories(web / "sub");
        std::ofstream(web / "index.html") << "<!doctype html><title>flyover</title>";
        std::ofstream(web / "app.js") << "console.log('flyover');";
        std::ofstream(web / "sub" / "x.css") << "body{}";
        std::ofstream(root / "secret.txt") << "TOP-SECRET-PATIENT-DATA";
        std::error_code ec;
        fs::create_symlink(root / "secret.txt", web / "link.txt", ec);
    }
};

class ViewSecurity : public ::testing::Test {
protected:
    static void SetUpTestSuite()
    {
        sAssets = new AssetFolder;
        sServer = new RunningServer(sharedStudy().study, sAssets->web.string());
    }
    static void TearDownTestSuite()
    {
        delete sServer;
        delete sAssets;
    }
    static inline AssetFolder* sAssets = nullptr;
    static inline RunningServer* sServer = nullptr;

    static void expectJsonError(const httplib::Result& r, int status, const std::string& what)
    {
        ASSERT_TRUE(r) << what << ": no answer";
        EXPECT_EQ(r->status, status) << what << ": " << r->body;
        const json j = json::parse(r->body, nullptr, false);
        ASSERT_TRUE(j.is_object() && j.contains("error")) << what << ": not a JSON error: " << r->body;
        const std::string e = j["error"];
        EXPECT_FALSE(e.empty());
        EXPECT_EQ(e.find('\n'), std::string::npos) << what;
    }
};

} // namespace

TEST_F(ViewSecurity, TokenIsRequiredEverywhere)
{
    auto anon = sServer->client(false);
    for (const char* path : {"/", "/assets/app.js", "/api/study", "/api/pair?arc_mm=0", "/api/bookmarks", "/nothing"})
        expectJsonError(anon->Get(path), 403, std::string("no token: ") + path);
    expectJsonError(anon->Get("/api/study?token=00"), 403, "wrong token in the query");
    httplib::Headers wrong{{"X-Flyover-Token", std::string(64, 'a')}};
    expectJsonError(anon->Get("/api/study", wrong), 403, "wrong token in the header");
    httplib::Headers cookie{{"Cookie", "flyover_token=" + std::string(64, 'b')}};
    expectJsonError(anon->Get("/api/study", cookie), 403, "wrong token in the cookie");

    const std::string token = sServer->server->token();
    EXPECT_EQ(token.size(), 64u);
    auto r = anon->Get(("/?token=" + token).c_str());
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200);
    EXPECT_NE(r->body.find("<title>flyover</title>"), std::string::npos);
    const std::string setCookie = r->get_header_value("Set-Cookie");
    EXPECT_NE(setCookie.find("flyover_token=" + token), std::string::npos);
    EXPECT_NE(setCookie.find("HttpOnly"), std::string::npos);
    EXPECT_NE(setCookie.find("SameSite=Strict"), std::string::npos);
    // With the cookie, relative URLs work (assets, <img src>).
    httplib::Headers good{{"Cookie", "theme=dark; flyover_token=" + token}};
    auto a = anon->Get("/assets/app.js", good);
    ASSERT_TRUE(a);
    EXPECT_EQ(a->status, 200);
    EXPECT_EQ(a->body, "console.log('flyover');");
    EXPECT_NE(a->get_header_value("Content-Type").find("javascript"), std::string::npos);
    EXPECT_EQ(anon->Get("/assets/sub/x.css", good)->status, 200);
}

TEST_F(ViewSecurity, ForeignHostIsRefused)
{
    auto c = sServer->client();
    const std::string port = std::to_string(sServer->port);
    for (const std::string& host : std::vector<std::string>{"evil.example:" + port, "evil.example", "127.0.0.1", "127.0.0.1:1", "localhost.evil:" + port,
                                   "0.0.0.0:" + port})
        expectJsonError(c->Get("/api/study", httplib::Headers{{"Host", host}}), 403, "Host " + host);
    EXPECT_EQ(c->Get("/api/study", httplib::Headers{{"Host", "localhost:" + port}})->status, 200);
}

TEST_F(ViewSecurity, StateChangesNeedTheServersOrigin)
{
    auto c = sServer->client();
    const std::string body = R"({"arc_mm": 1})";
    expectJsonError(c->Post("/api/bookmarks", body, "application/json"), 403, "POST without Origin");
    expectJsonError(c->Post("/api/bookmarks", httplib::Headers{{"Origin", "http://evil.example"}}, body, "application/json"),
                    403, "POST with a foreign Origin");
    expectJsonError(c->Post("/api/bookmarks", httplib::Headers{{"Origin", "null"}}, body, "application/json"), 403,
                    "POST with Origin null");
    expectJsonError(c->Delete("/api/bookmarks?id=b1", httplib::Headers{{"Origin", "http://127.0.0.1:1"}}), 403,
                    "DELETE with another port's Origin");
    expectJsonError(c->Post("/api/screenshot", httplib::Headers{{"Origin", "http://evil.example"}}, body, "application/json"),
                    403, "screenshot with a foreign Origin");
    expectJsonError(c->Post("/api/bookmarks",
                            httplib::Headers{{"Origin", sServer->origin()}, {"Sec-Fetch-Site", "cross-site"}}, body,
                            "application/json"),
                    403, "cross-site fetch");
    EXPECT_FALSE(fs::exists(sharedStudy().study + "/bookmarks.json")) << "a refused request wrote a bookmark";
}

TEST_F(ViewSecurity, NoPathLeavesTheAssets)
{
    auto c = sServer->client();
    for (const char* path :
         {"/../../etc/passwd", "/assets/../../etc/passwd", "/assets/..%2f..%2fetc/passwd", "/assets/%2e%2e/%2e%2e/etc/passwd",
          "/assets/%2e%2e%2fsecret.txt", "/assets/../secret.txt", "/assets//etc/passwd", "/assets/link.txt",
          "/assets/sub/../../secret.txt", "/assets/%252e%252e/secret.txt", "/assets/.%2e/secret.txt",
          "/api/screenshots/..%2f..%2fct.vdb", "/api/screenshots/../manifest.json", "/api/screenshots/shot_..%2fx.png",
          "/etc/passwd", "/assets/", "/assets"}) {
        auto r = c->Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_GE(r->status, 400) << path;
        EXPECT_LT(r->status, 500) << path;
        EXPECT_EQ(r->body.find("root:"), std::string::npos) << path;
        EXPECT_EQ(r->body.find("TOP-SECRET"), std::string::npos) << path;
    }
}

TEST_F(ViewSecurity, BadParametersAreOneLineJsonErrors)
{
    auto c = sServer->client();
    expectJsonError(c->Get("/api/pair?arc_mm=nan"), 400, "NaN");
    expectJsonError(c->Get("/api/pair?arc_mm=inf"), 400, "inf");
    expectJsonError(c->Get("/api/pair?arc_mm=1e999"), 400, "overflow");
    expectJsonError(c->Get("/api/pair?arc_mm=12abc"), 400, "trailing junk");
    expectJsonError(c->Get("/api/pair?arc_mm="), 400, "empty");
    expectJsonError(c->Get("/api/pair?arc_mm=1e6"), 422, "arc beyond the path");
    expectJsonError(c->Get("/api/pair?arc_mm=-5"), 422, "negative arc");
    expectJsonError(c->Get("/api/pair?arc_mm=1&px=100000"), 422, "px too large");
    expectJsonError(c->Get("/api/pair?arc_mm=1&px=64.5"), 400, "fractional px");
    expectJsonError(c->Get("/api/pair?arc_mm=1&zoom=2"), 400, "unknown parameter");
    expectJsonError(c->Get("/api/pair?arc_mm=1&arc_mm=2"), 400, "repeated parameter");
    expectJsonError(c->Get("/api/pair?arc_mm=1&direction=up"), 400, "bad direction");
    expectJsonError(c->Get("/api/pair?arc_mm=1&format=gif"), 400, "bad format");
    expectJsonError(c->Get("/api/pair?arc_mm=1&clip_offset_fraction=3"), 422, "clip offset");
    expectJsonError(c->Get("/api/pick?arc_mm=1&view=2&x=1&y=1"), 422, "view 2");
    expectJsonError(c->Get("/api/pick?arc_mm=1&view=0&x=1"), 400, "y missing");
    expectJsonError(c->Get("/api/pick?arc_mm=1&view=0&x=-1&y=1"), 422, "x outside");
    expectJsonError(c->Get("/api/locate?x_mm=1&y_mm=2"), 400, "z missing");
    expectJsonError(c->Get("/api/overview?marker_mm=-1"), 422, "marker off the path");
    expectJsonError(c->Get("/api/slice?plane=axial&x_mm=0&y_mm=0&z_mm=0&window=0"), 422, "window 0");
    expectJsonError(c->Get("/api/nothing"), 404, "unknown API path");
    expectJsonError(c->Put("/api/bookmarks", "{}", "application/json"), 403, "PUT without Origin");
    expectJsonError(c->Put("/api/bookmarks", httplib::Headers{{"Origin", sServer->origin()}}, "{}", "application/json"), 405,
                    "PUT");
    expectJsonError(c->Post("/api/pair", httplib::Headers{{"Origin", sServer->origin()}}, "{}", "application/json"), 405,
                    "POST to a GET path");
    const std::string big(200 * 1024, ' ');
    auto r = c->Post("/api/bookmarks", httplib::Headers{{"Origin", sServer->origin()}}, big, "application/json");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 413);
    // The server still answers.
    EXPECT_EQ(c->Get("/api/study")->status, 200);
}

TEST_F(ViewSecurity, RandomRequestsAreAllAnsweredAndNothingLeaks)
{
    std::mt19937 rng(12345);
    auto pickOne = [&](const std::vector<std::string>& v) { return v[std::uniform_int_distribution<std::size_t>(0, v.size() - 1)(rng)]; };
    const std::vector<std::string> paths = {"/", "/index.html", "/assets/", "/assets/app.js", "/assets/sub/x.css",
                                            "/api/study", "/api/pair", "/api/pick", "/api/locate", "/api/slice",
                                            "/api/overview", "/api/overview/pick", "/api/bookmarks", "/api/screenshot",
                                            "/api/screenshots/", "/../", "/assets/..", "/%2e%2e/", "/etc/passwd", "//"};
    const std::vector<std::string> names = {"arc_mm", "roll_deg", "direction", "mode", "px", "format", "x", "y", "view",
                                            "x_mm", "y_mm", "z_mm", "plane", "window", "level", "marker_mm", "id",
                                            "clip_offset_fraction", "token", "zzz"};
    const std::vector<std::string> values = {"0", "1", "-1", "nan", "inf", "1e308", "-1e308", "64", "100000", "left",
                                             "right", "png", "jpeg", "axial", "flythrough", "", "%00", "..%2f", "0x10",
                                             "3.5", "1,2", "%ff%fe", "2047"};
    const std::vector<std::string> methods = {"GET", "POST", "DELETE", "PUT", "PATCH", "OPTIONS", "HEAD"};
    const std::string token = sServer->server->token();
    const std::string port = std::to_string(sServer->port);
    auto c = sServer->client(false);
    int answered = 0;
    const int total = 300;
    for (int n = 0; n < total; ++n) {
        std::string path = pickOne(paths);
        if (rng() % 4 == 0) {
            // random bytes, percent-encoded
            for (int k = 0, len = int(rng() % 12); k < len; ++k) {
                char buf[4];
                std::snprintf(buf, sizeof buf, "%%%02X", unsigned(rng() % 256));
                path += buf;
            }
        }
        std::string query;
        for (int k = 0, m = int(rng() % 6); k < m; ++k)
            query += (query.empty() ? "?" : "&") + pickOne(names) + "=" + pickOne(values);
        httplib::Headers headers;
        if (rng() % 5 != 0) headers.emplace("X-Flyover-Token", rng() % 10 == 0 ? std::string(64, 'c') : token);
        if (rng() % 6 == 0) headers.emplace("Host", rng() % 2 ? "evil.example:" + port : "localhost:" + port);
        if (rng() % 3 == 0) headers.emplace("Origin", rng() % 2 ? "http://evil.example" : sServer->origin());
        const std::string method = pickOne(methods);
        httplib::Request req;
        req.method = method;
        req.path = path + query;
        req.headers = headers;
        if (method == "POST" || method == "PUT" || method == "PATCH") {
            req.body = rng() % 2 ? R"({"arc_mm": 10, "note": "x"})" : std::string(rng() % 300, char('a' + rng() % 26));
            req.headers.emplace("Content-Type", "application/json");
        }
        auto res = c->send(req);
        ASSERT_TRUE(res) << method << " " << req.path << ": no answer (" << httplib::to_string(res.error()) << ")";
        ++answered;
        EXPECT_GE(res->status, 200) << req.path;
        EXPECT_LT(res->status, 500) << method << " " << req.path << ": " << res->body;
        EXPECT_EQ(res->body.find("root:"), std::string::npos) << req.path;
        EXPECT_EQ(res->body.find("TOP-SECRET"), std::string::npos) << req.path;
        if (res->status == 200 && path.rfind("/assets/", 0) == 0 && method == "GET") {
            EXPECT_TRUE(res->body == "console.log('flyover');" || res->body == "body{}") << req.path;
        }
    }
    EXPECT_EQ(answered, total);
    auto alive = sServer->client()->Get("/api/study");
    ASSERT_TRUE(alive);
    EXPECT_EQ(alive->status, 200);
    std::error_code ec;
    fs::remove(sharedStudy().study + "/bookmarks.json", ec);
    fs::remove_all(sharedStudy().study + "/screenshots", ec);
}
