#include "view/view_server.h"

#include "pipeline/artifact_io.h"
#include "view/finding_store.h"
#include "view/findings_routes.h"
#include "view/http_request.h"
#include "view/image_codec.h"
#include "volume/error.h"
#include "volume/image.h"

#include <httplib.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <pthread.h>
#include <set>
#include <sstream>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

using namespace http;
constexpr std::size_t MAX_ASSET_BYTES = 16u << 20;
constexpr std::size_t MAX_ASSETS = 512;

std::string randomToken()
{
    unsigned char bytes[32];
    std::ifstream in("/dev/urandom", std::ios::binary);
    if (!in.read(reinterpret_cast<char*>(bytes), sizeof bytes))
        throw std::runtime_error("view: cannot read /dev/urandom for the session token");
    static const char* hex = "0123456789abcdef";
    std::string t;
    for (unsigned char b : bytes) t += hex[b >> 4], t += hex[b & 15];
    return t;
}

/// Compares without an early exit, so the time taken says nothing about the token.
bool sameSecret(const std::string& a, const std::string& b)
{
    if (a.size() != b.size()) return false;
    unsigned char diff = 0;
    for (std::size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
    return diff == 0;
}

std::string mimeOf(const std::string& name)
{
    const std::string ext = fs::path(name).extension().string();
    static const std::map<std::string, std::string> types = {
        {".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"},
        {".mjs", "text/javascript; charset=utf-8"}, {".css", "text/css; charset=utf-8"},
        {".json", "application/json"},          {".png", "image/png"},
        {".jpg", "image/jpeg"},                 {".svg", "image/svg+xml"},
        {".ico", "image/x-icon"},               {".txt", "text/plain; charset=utf-8"},
        {".woff2", "font/woff2"}};
    const auto it = types.find(ext);
    return it == types.end() ? "application/octet-stream" : it->second;
}

/// The value of cookie `name` in a Cookie header, or "".
std::string cookieValue(const std::string& header, const std::string& name)
{
    std::size_t start = 0;
    while (start < header.size()) {
        std::size_t end = header.find(';', start);
        if (end == std::string::npos) end = header.size();
        std::string part = header.substr(start, end - start);
        const std::size_t b = part.find_first_not_of(' ');
        part = b == std::string::npos ? "" : part.substr(b);
        if (part.size() > name.size() && part.compare(0, name.size(), name) == 0 && part[name.size()] == '=')
            return part.substr(name.size() + 1);
        start = end + 1;
    }
    return "";
}

std::string exeDir()
{
    std::error_code ec;
    const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
    return ec ? std::string() : exe.parent_path().string();
}

/// One request as the route handlers see it: the request and answer, the server's state they
/// may use, and (for every path but the page, its assets and the status) the study of the
/// latest revision.
struct RouteCall {
    const httplib::Request& req;
    httplib::Response& res;
    const std::string& path;
    const std::string& method;
    bool get;
    const std::map<std::string, ViewServer::Asset>& assets;
    const std::string& assetDir;
    const std::string& token;
    LiveStudy& live;
    BookmarkStore& bookmarks;
    FindingStore& findings;
    std::atomic<unsigned>& shotCounter;
    std::shared_ptr<const ViewStudy> held;
    const ViewStudy* study = nullptr;
    int revision = 0;

    void onlyGet() const
    {
        if (!get) throw HttpError(405, method + " " + path + ": only GET");
    }
    int defaultPx() const { return std::min(study->renderParams().heightPx, study->maxPx()); }

    /// A pose from the query (pair, pick, screenshot share it).
    ViewPose poseFrom(const Query& q) const
    {
        ViewPose pose;
        pose.arcMm = q.number("arc_mm", 0.0);
        pose.rollDeg = q.number("roll_deg", study->renderParams().rollDeg, -3600, 3600);
        pose.direction = q.choice("direction", study->renderParams().direction, {"right", "left"});
        pose.mode = q.choice("mode", "flyover", {"flyover", "flythrough"});
        pose.clipOffsetFraction = q.has("clip_offset_fraction") ? q.number("clip_offset_fraction", 0.5, 0.0, 1.0) : -1.0;
        pose.px = q.integer("px", defaultPx(), 16, study->maxPx());
        study->indexOfArc(pose.arcMm);  // 422 when off the path
        return pose;
    }
    ViewPose poseFromJson(const json& body) const
    {
        ViewPose pose;
        pose.arcMm = jsonNumber(body, "arc_mm", 0.0, -1e9, 1e9);
        pose.rollDeg = jsonNumber(body, "roll_deg", study->renderParams().rollDeg, -3600, 3600);
        pose.direction = jsonChoice(body, "direction", study->renderParams().direction, {"right", "left"});
        pose.mode = jsonChoice(body, "mode", "flyover", {"flyover", "flythrough"});
        pose.clipOffsetFraction = jsonNumber(body, "clip_offset_fraction", -1.0, 0.0, 1.0);
        if (body.contains("clip_offset_fraction") && body["clip_offset_fraction"].is_null()) pose.clipOffsetFraction = -1;
        pose.px = int(jsonNumber(body, "px", defaultPx(), 16, study->maxPx()));
        study->indexOfArc(pose.arcMm);
        return pose;
    }
    json poseSummary(const ViewPose& p) const
    {
        return json{{"arc_mm", p.arcMm},
                    {"roll_deg", p.rollDeg},
                    {"direction", p.direction},
                    {"mode", p.mode},
                    {"clip_offset_fraction", p.clipOffsetFraction < 0 ? study->renderParams().clipOffsetFraction : p.clipOffsetFraction}};
    }
};

struct Route {
    const char* path;
    bool prefix;  ///< the path starts with it
    void (*handle)(RouteCall&);
};

const Route* findRoute(const Route* first, const Route* last, const std::string& path)
{
    for (const Route* r = first; r != last; ++r)
        if (r->prefix ? path.rfind(r->path, 0) == 0 : path == r->path) return r;
    return nullptr;
}

/// /, /index.html
void servePage(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    c.onlyGet();
    Query q(req, {});
    const auto it = c.assets.find("index.html");
    if (it == c.assets.end())
        throw HttpError(404, "the page is not installed: no index.html in " +
                                 (c.assetDir.empty() ? std::string("(no asset folder)") : c.assetDir));
    // The cookie lets <img src> and the page's assets load without the token in every URL.
    if (req.has_param("token"))
        res.set_header("Set-Cookie", "flyover_token=" + c.token + "; HttpOnly; SameSite=Strict; Path=/");
    res.set_header("Content-Security-Policy",
                   "default-src 'self'; img-src 'self' blob: data:; style-src 'self' 'unsafe-inline'; "
                   "script-src 'self'; connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'");
    res.set_content(it->second.body, it->second.mime);
}

/// /assets/
void serveAssets(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    auto& path = c.path;
    c.onlyGet();
    Query q(req, {});
    const auto it = c.assets.find(path.substr(8));
    if (it == c.assets.end()) throw HttpError(404, "no such asset");
    res.set_content(it->second.body, it->second.mime);
}

/// /api/status
void serveApiStatus(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    c.onlyGet();
    Query q(req, {});
    sendJson(res, c.live.status());
}

/// /api/study
void serveApiStudy(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    const auto revision = c.revision;
    c.onlyGet();
    Query q(req, {});
    json j = study.studyJson();
    j["revision"] = revision;
    sendJson(res, j);
}

/// /api/pair
void serveApiPair(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    c.onlyGet();
    Query q(req, {"arc_mm", "roll_deg", "direction", "mode", "clip_offset_fraction", "px", "format", "quality"});
    const ViewPose pose = c.poseFrom(q);
    const std::string format = q.choice("format", "jpeg", {"jpeg", "png"});
    const int quality = q.integer("quality", 88, 1, 100);
    const PairRender pr = study.renderPair(pose);
    res.set_header("X-Flyover-Pose", pr.poseJson.dump());
    if (format == "png") res.set_content(encodePng(pr.image), "image/png");
    else res.set_content(encodeJpeg(pr.image, quality), "image/jpeg");
}

/// /api/pick
void serveApiPick(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    c.onlyGet();
    Query q(req, {"arc_mm", "roll_deg", "direction", "mode", "clip_offset_fraction", "px", "view", "x", "y"});
    const ViewPose pose = c.poseFrom(q);
    const int view = q.integer("view", 0, 0, 1);
    const double x = q.number("x"), y = q.number("y");
    if (x < 0 || x > pose.px || y < 0 || y > pose.px)
        throw HttpError(422, "x, y: must lie in [0, px] = [0, " + std::to_string(pose.px) + "]");
    const PickResult r = study.pick(pose, view, x, y);
    json j{{"hit", r.hit}, {"world_frame", WORLD_FRAME}, {"view", view}, {"x", x}, {"y", y}};
    if (r.hit) {
        j["point_mm"] = json::array({r.pointMm.x, r.pointMm.y, r.pointMm.z});
        j["distance_mm"] = r.distanceMm;
        j["triangle"] = r.triangle;
    } else {
        j["point_mm"] = nullptr;
        j["distance_mm"] = nullptr;
        j["triangle"] = nullptr;
    }
    sendJson(res, j);
}

/// /api/locate
void serveApiLocate(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    const RenderParams& rp = c.study->renderParams();
    const auto defaultPx = c.defaultPx();
    c.onlyGet();
    Query q(req, {"x_mm", "y_mm", "z_mm", "px", "direction"});
    const Vec3d p{q.number("x_mm"), q.number("y_mm"), q.number("z_mm")};
    const int px = q.integer("px", defaultPx, 16, study.maxPx());
    const std::string direction = q.choice("direction", rp.direction, {"right", "left"});
    const LocateResult r = study.locate(p, px, direction);
    sendJson(res, json{{"arc_mm", r.pose.arcMm},
                       {"roll_deg", r.pose.rollDeg},
                       {"direction", r.pose.direction},
                       {"mode", r.pose.mode},
                       {"view", r.view},
                       {"x", r.x},
                       {"y", r.y},
                       {"px", px},
                       {"centerline_index", r.centerlineIndex},
                       {"world_frame", WORLD_FRAME}});
}

/// /api/slice
void serveApiSlice(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    c.onlyGet();
    Query q(req, {"plane", "x_mm", "y_mm", "z_mm", "window", "level"});
    if (!study.hasCt())
        throw HttpError(404, "this study has no CT (mask only): restart the viewer with --ct FILE for slices");
    const std::string plane = q.choice("plane", "axial", {"axial", "coronal", "sagittal"});
    const Vec3d p{q.number("x_mm"), q.number("y_mm"), q.number("z_mm")};
    const double window = q.number("window", 1500, 1, 100000);
    const double level = q.number("level", -300, -100000, 100000);
    const json info = study.studyJson()["ct"];
    const json& lo = info["bounds_mm"][0];
    const json& hi = info["bounds_mm"][1];
    const double coord[3] = {p.x, p.y, p.z};
    const int axis = plane == "axial" ? 2 : plane == "coronal" ? 1 : 0;
    const double slack = info["spacing_mm"][std::size_t(axis)].get<double>();
    if (coord[axis] < lo[std::size_t(axis)].get<double>() - slack || coord[axis] > hi[std::size_t(axis)].get<double>() + slack)
        throw HttpError(422, std::string(axis == 2 ? "z_mm" : axis == 1 ? "y_mm" : "x_mm") + ": " +
                                 Query::shortNumber(coord[axis]) + " is outside the CT");
    const SliceImage s = study.slice(plane, p, window, level);
    const SliceGeometry& g = s.geometry;
    auto v = [](const Vec3d& a) { return json::array({a.x, a.y, a.z}); };
    res.set_header("X-Flyover-Slice",
                   json{{"plane", g.plane},
                        {"world_frame", WORLD_FRAME},
                        {"width", g.width},
                        {"height", g.height},
                        {"origin_mm", v(g.originMm)},
                        {"row_dir", v(g.rowDir)},
                        {"col_dir", v(g.colDir)},
                        {"pixel_mm", g.pixelMm},
                        {"point_mm", v(p)},
                        {"window", window},
                        {"level", level},
                        {"rule", "pixel (c, r) centre = origin_mm + c*pixel_mm*col_dir + r*pixel_mm*row_dir"}}
                       .dump());
    res.set_content(encodeGrayPng(g.width, g.height, s.gray), "image/png");
}

/// /api/overview
void serveApiOverview(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    const RenderParams& rp = c.study->renderParams();
    c.onlyGet();
    Query q(req, {"marker_mm", "px", "findings"});
    const int px = q.integer("px", std::min(rp.overviewPx, study.maxPx()), 16, study.maxPx());
    double marker = -1;
    if (q.has("marker_mm")) {
        marker = q.number("marker_mm");
        study.indexOfArc(marker);
    }
    std::vector<OverviewMarker> marks;
    if (q.integer("findings", 0, 0, 1) == 1) {
        // The page's colours (view/web/findings.js); the ring a little wider than the finding.
        static const std::map<std::string, std::array<uint8_t, 3>> colours = {
            {"unreviewed", {74, 209, 255}}, {"accepted", {107, 214, 139}}, {"hand", {255, 159, 67}}};
        for (const FindingMark& m : c.findings.marks())
            marks.push_back(OverviewMarker{m.positionMm, 0.5 * m.sizeMm + 3.0, colours.at(m.kind), false});
    }
    res.set_content(encodePng(study.overview(px, marker, marks)), "image/png");
}

/// /api/overview/pick
void serveApiOverviewPick(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    const ViewStudy& study = *c.study;
    const RenderParams& rp = c.study->renderParams();
    c.onlyGet();
    Query q(req, {"x", "y", "px"});
    const int px = q.integer("px", std::min(rp.overviewPx, study.maxPx()), 16, study.maxPx());
    const double x = q.number("x"), y = q.number("y");
    if (x < 0 || x > px || y < 0 || y > px)
        throw HttpError(422, "x, y: must lie in [0, px] = [0, " + std::to_string(px) + "]");
    const auto r = study.overviewPick(px, x, y);
    json j{{"hit", r.hit}, {"world_frame", WORLD_FRAME}, {"point_mm", nullptr}, {"arc_mm", nullptr}};
    if (r.hit) {
        j["point_mm"] = json::array({r.pointMm.x, r.pointMm.y, r.pointMm.z});
        j["arc_mm"] = r.arcMm;
    }
    sendJson(res, j);
}

/// /api/bookmarks
void serveApiBookmarks(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    auto& method = c.method;
    const auto get = c.get;
    if (get) {
        Query q(req, {});
        sendJson(res, json{{"bookmarks", c.bookmarks.list()}, {"world_frame", WORLD_FRAME}});
    } else if (method == "POST") {
        Query q(req, {});
        const json body = parseBody(req);
        static const std::set<std::string> fields = {"note", "arc_mm", "roll_deg", "direction", "mode",
                                                     "clip_offset_fraction", "px"};
        for (auto it = body.begin(); it != body.end(); ++it)
            if (!fields.count(it.key())) throw HttpError(400, "body: unknown field '" + it.key().substr(0, 40) + "'");
        if (!body.contains("arc_mm")) throw HttpError(400, "arc_mm: missing");
        std::string note;
        if (body.contains("note")) {
            if (!body["note"].is_string()) throw HttpError(400, "note: must be a string");
            note = body["note"].get<std::string>();
            if (note.size() > 2000) throw HttpError(422, "note: longer than 2000 bytes");
        }
        const ViewPose pose = c.poseFromJson(body);
        json b = c.poseSummary(pose);
        b["note"] = note;
        sendJson(res, c.bookmarks.add(b), 201);
    } else if (method == "DELETE") {
        Query q(req, {"id"});
        if (!q.has("id")) throw HttpError(400, "id: missing");
        if (!c.bookmarks.remove(q.text("id"))) throw HttpError(404, "no bookmark with id '" + q.text("id").substr(0, 40) + "'");
        sendJson(res, json{{"deleted", q.text("id")}});
    } else {
        throw HttpError(405, method + " /api/bookmarks: GET, POST or DELETE");
    }
}

/// /api/findings, /api/findings/... (view/findings_routes.h)
void serveApiFindings(RouteCall& c) { serveFindings(c.req, c.res, c.findings, *c.study); }

/// /api/screenshot
void serveApiScreenshot(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    auto& method = c.method;
    const ViewStudy& study = *c.study;
    if (method != "POST") throw HttpError(405, method + " /api/screenshot: only POST");
    Query q(req, {});
    const json body = parseBody(req);
    static const std::set<std::string> fields = {"note", "arc_mm", "roll_deg", "direction", "mode",
                                                 "clip_offset_fraction", "px"};
    for (auto it = body.begin(); it != body.end(); ++it)
        if (!fields.count(it.key())) throw HttpError(400, "body: unknown field '" + it.key().substr(0, 40) + "'");
    const ViewPose pose = c.poseFromJson(body);
    const PairRender pr = study.renderPair(pose);
    const fs::path dir = fs::path(study.studyDir()) / "screenshots";
    fs::create_directories(dir);
    const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&now, &tm);
    char stamp[32];
    std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &tm);
    std::string name;
    for (unsigned k = 0;; ++k) {
        name = "shot_" + std::string(stamp) + "_" + std::to_string(::getpid() % 100000) + "_" +
               std::to_string(c.shotCounter++) ;
        if (!fs::exists(dir / (name + ".png"))) break;
        if (k > 1000) throw HttpError(500, "screenshots: no free file name");
    }
    json pj = pr.poseJson;
    pj["schema"] = "flyover.screenshot/1";
    pj["image"] = name + ".png";
    pj["layout"] = "camera 0 left, camera 1 right";
    if (body.contains("note") && body["note"].is_string()) pj["note"] = body["note"];
    writePng((dir / (name + ".png")).string(), pr.image);
    writeJson((dir / (name + ".json")).string(), pj);
    sendJson(res,
             json{{"file", "screenshots/" + name + ".png"},
                  {"pose_file", "screenshots/" + name + ".json"},
                  {"url", "/api/screenshots/" + name + ".png"},
                  {"pose", pj}},
             201);
}

/// /api/screenshots/
void serveApiScreenshots(RouteCall& c)
{
    auto& req = c.req;
    auto& res = c.res;
    auto& path = c.path;
    const ViewStudy& study = *c.study;
    c.onlyGet();
    Query q(req, {});
    const std::string name = path.substr(17);
    bool ok = name.size() > 9 && name.size() < 100 && name.rfind("shot_", 0) == 0;
    for (char c : name) ok = ok && (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.');
    const std::string ext = fs::path(name).extension().string();
    ok = ok && (ext == ".png" || ext == ".json") && name.find("..") == std::string::npos;
    const fs::path file = fs::path(study.studyDir()) / "screenshots" / name;
    if (!ok || fs::is_symlink(file) || !fs::is_regular_file(file)) throw HttpError(404, "no such screenshot");
    std::ifstream in(file, std::ios::binary);
    std::string body((std::istreambuf_iterator<char>(in)), {});
    res.set_header("Content-Disposition", "attachment; filename=\"" + name + "\"");
    res.set_content(body, ext == ".png" ? "image/png" : "application/json");
}

} // namespace

std::string defaultAssetDir()
{
    if (const char* env = std::getenv("FLYOVER_VIEW_ASSETS"); env && *env) return env;
    const std::string dir = exeDir();
    if (!dir.empty()) {
        const fs::path installed = fs::path(dir) / ".." / "share" / "flyover" / "web";
        if (fs::is_directory(installed)) return fs::weakly_canonical(installed).string();
    }
#ifdef FLYOVER_VIEW_BUILD_ASSETS
    return FLYOVER_VIEW_BUILD_ASSETS;
#else
    return "";
#endif
}

ViewServer::ViewServer(LiveStudy& study, const ViewServerOptions& options)
    : mLive(study), mServer(std::make_unique<httplib::Server>()), mToken(options.token),
      mPort(options.port), mThreads(std::max(2, options.threads))
{
    if (mToken.empty()) mToken = randomToken();
    if (mPort < 0 || mPort > 65535) throw ParameterError("--port: must be 0..65535");
    mBookmarks = std::make_unique<BookmarkStore>((fs::path(mLive.studyDir()) / "bookmarks.json").string());
    mFindings = std::make_unique<FindingStore>(mLive.studyDir());

    // The page's files, read once: requests are answered from this map only.
    mAssetDir = options.assetDir.empty() ? defaultAssetDir() : options.assetDir;
    if (!mAssetDir.empty() && fs::is_directory(mAssetDir)) {
        for (auto it = fs::recursive_directory_iterator(mAssetDir, fs::directory_options::none);
             it != fs::recursive_directory_iterator(); ++it) {
            if (it->is_symlink() || !it->is_regular_file()) continue;
            const std::string rel = fs::relative(it->path(), mAssetDir).generic_string();
            if (rel.empty() || rel[0] == '.' || rel.find("/.") != std::string::npos) continue;
            if (it->file_size() > MAX_ASSET_BYTES || mAssets.size() >= MAX_ASSETS) continue;
            std::ifstream in(it->path(), std::ios::binary);
            std::string body((std::istreambuf_iterator<char>(in)), {});
            mAssets[rel] = Asset{std::move(body), mimeOf(rel)};
        }
    }

    httplib::Server& s = *mServer;
    const int threads = mThreads;
    s.new_task_queue = [threads] { return new httplib::ThreadPool(std::size_t(threads)); };
    s.set_payload_max_length(MAX_BODY_BYTES);
    s.set_keep_alive_max_count(10000);
    s.set_keep_alive_timeout(5);
    s.set_tcp_nodelay(true);
    s.set_read_timeout(10, 0);
    s.set_write_timeout(10, 0);
    auto handler = [this](const httplib::Request& req, httplib::Response& res) { handle(req, res); };
    s.Get(".*", handler);
    s.Post(".*", handler);
    s.Delete(".*", handler);
    s.Put(".*", handler);
    s.Patch(".*", handler);
    s.Options(".*", handler);
    // httplib's own refusals (bad request line, 413, 414, ...) as JSON too.
    s.set_error_handler([](const httplib::Request&, httplib::Response& res) {
        if (res.body.empty())
            sendJson(res, json{{"error", "HTTP " + std::to_string(res.status) +
                                             (res.status == 413 ? ": request body larger than 64 KiB"
                                              : res.status == 414 ? ": request line too long"
                                                                  : ": bad request")}},
                     res.status);
    });
    s.set_exception_handler([](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
        std::string what = "internal error";
        try {
            if (ep) std::rethrow_exception(ep);
        } catch (const std::exception& e) {
            what = e.what();
        } catch (...) {
        }
        sendJson(res, json{{"error", oneLine(what)}}, 500);
    });
}

ViewServer::~ViewServer() { stop(); }

int ViewServer::bind()
{
    int port = mPort == 0 ? mServer->bind_to_any_port("127.0.0.1") : (mServer->bind_to_port("127.0.0.1", mPort) ? mPort : -1);
    if (port <= 0)
        throw InputError("view: cannot listen on 127.0.0.1:" + std::to_string(mPort) + " (in use?)");
    mPort = port;
    return mPort;
}

void ViewServer::listen() { mServer->listen_after_bind(); }
void ViewServer::stop()
{
    if (mServer) mServer->stop();
}
bool ViewServer::isRunning() const { return mServer->is_running(); }

std::string ViewServer::url() const { return "http://127.0.0.1:" + std::to_string(mPort) + "/?token=" + mToken; }

bool ViewServer::allowed(const httplib::Request& req, httplib::Response& res) const
{
    const std::string port = std::to_string(mPort);
    const std::string host = req.get_header_value("Host");
    if (host != "127.0.0.1:" + port && host != "localhost:" + port) {
        sendJson(res, json{{"error", "refused: the Host header must be 127.0.0.1:" + port + " or localhost:" + port}}, 403);
        return false;
    }
    std::string given;
    if (req.has_param("token")) given = req.get_param_value("token");
    else if (req.has_header("X-Flyover-Token")) given = req.get_header_value("X-Flyover-Token");
    else given = cookieValue(req.get_header_value("Cookie"), "flyover_token");
    if (!sameSecret(given, mToken)) {
        sendJson(res, json{{"error", given.empty() ? "refused: this server needs the token of its URL"
                                                   : "refused: wrong token"}},
                 403);
        return false;
    }
    if (req.method != "GET" && req.method != "HEAD") {
        const std::string origin = req.get_header_value("Origin");
        if (origin != "http://127.0.0.1:" + port && origin != "http://localhost:" + port) {
            sendJson(res, json{{"error", "refused: " + req.method + " needs the Origin of this server (http://127.0.0.1:" +
                                             port + ")"}},
                     403);
            return false;
        }
        const std::string site = req.get_header_value("Sec-Fetch-Site");
        if (!site.empty() && site != "same-origin" && site != "none") {
            sendJson(res, json{{"error", "refused: cross-site request"}}, 403);
            return false;
        }
    }
    return true;
}

void ViewServer::handle(const httplib::Request& req, httplib::Response& res)
{
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Content-Type-Options", "nosniff");
    res.set_header("Referrer-Policy", "no-referrer");
    res.set_header("X-Frame-Options", "DENY");
    if (!allowed(req, res)) return;
    try {
        route(req, res);
    } catch (const HttpError& e) {
        sendJson(res, json{{"error", oneLine(e.what())}}, e.status);
    } catch (const RangeError& e) {
        sendJson(res, json{{"error", oneLine(e.what())}}, 422);
    } catch (const ParameterError& e) {
        sendJson(res, json{{"error", oneLine(e.what())}}, 400);
    } catch (const StudyNotReady& e) {
        res.set_header("Retry-After", "1");
        sendJson(res, json{{"error", oneLine(e.what())}}, 503);
    } catch (const InputError& e) {
        sendJson(res, json{{"error", oneLine(e.what())}}, 500);
    }
}

void ViewServer::route(const httplib::Request& req, httplib::Response& res)
{
    // The page, its assets and the status answer without a study; every other path is answered
    // by the study of the latest revision (503 while none).
    static const Route WITHOUT_STUDY[] = {
        {"/", false, servePage},
        {"/index.html", false, servePage},
        {"/assets/", true, serveAssets},
        {"/api/status", false, serveApiStatus},
    };
    static const Route WITH_STUDY[] = {
        {"/api/study", false, serveApiStudy},
        {"/api/pair", false, serveApiPair},
        {"/api/pick", false, serveApiPick},
        {"/api/locate", false, serveApiLocate},
        {"/api/slice", false, serveApiSlice},
        {"/api/overview", false, serveApiOverview},
        {"/api/overview/pick", false, serveApiOverviewPick},
        {"/api/bookmarks", false, serveApiBookmarks},
        {"/api/findings", false, serveApiFindings},
        {"/api/findings/", true, serveApiFindings},
        {"/api/screenshot", false, serveApiScreenshot},
        {"/api/screenshots/", true, serveApiScreenshots},
    };
    RouteCall c{req, res, req.path, req.method, req.method == "GET" || req.method == "HEAD", mAssets, mAssetDir, mToken,
                mLive, *mBookmarks, *mFindings, mShotCounter, nullptr};
    if (const Route* r = findRoute(std::begin(WITHOUT_STUDY), std::end(WITHOUT_STUDY), c.path)) return r->handle(c);
    c.held = mLive.current(&c.revision);
    c.study = c.held.get();
    if (const Route* r = findRoute(std::begin(WITH_STUDY), std::end(WITH_STUDY), c.path)) return r->handle(c);
    throw HttpError(404, "no such path: " + c.path.substr(0, 80));
}

namespace {

/// Blocks SIGINT and SIGTERM in this thread (and every thread started from now on): they are
/// taken by sigwait in the watcher thread, which stops the server outside any signal handler.
sigset_t blockStopSignals()
{
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGHUP);
    pthread_sigmask(SIG_BLOCK, &set, nullptr);
    return set;
}

} // namespace

int runViewCommand(const std::string& studyDir, int port, const std::string& ctPath, std::ostream& out)
{
    const sigset_t stopSignals = blockStopSignals();
    LiveStudy study(studyDir, ctPath);
    // The surface and CT load in the background: the URL is printed at once, and requests wait
    // for the load (a failure of the study there at start ends the server with its message).
    // A study that a run is still computing is served once its surface and centerline are
    // written; later changes to its files are picked up (live_study.h).
    study.start();
    ViewServer server(study, ViewServerOptions{port, "", "", 16});
    server.bind();
    std::atomic<bool> stopping{false}, listenDone{false};
    std::string loadFailure;
    // stop() only stops a server that is listening: wait for that (or for listen's end).
    auto stopServer = [&] {
        while (!server.isRunning() && !listenDone) std::this_thread::sleep_for(std::chrono::milliseconds(5));
        server.stop();
    };
    std::thread watcher([&] {
        int sig = 0;
        sigwait(&stopSignals, &sig);
        stopping = true;
        stopServer();
    });
    std::atomic<bool> firstLoaded{false};
    std::thread loadWatch([&] {
        try {
            study.waitFirstLoad();
        } catch (const std::exception& e) {
            loadFailure = e.what();
            stopServer();
        }
        firstLoaded = true;
    });
    out << "flyover: view: " << server.url() << std::endl;
    if (const std::string why = study.notReadyReason(); !why.empty())
        out << "flyover: view: " << studyDir << ": " << why << "; the page shows it once they are written"
            << std::endl;
    server.listen();
    listenDone = true;
    if (stopping && !firstLoaded) {
        // Stopped while the study is still loading: nothing to save, do not wait for the load.
        watcher.join();
        out.flush();
        std::_Exit(0);
    }
    loadWatch.join();
    study.stop();
    if (!stopping) pthread_kill(watcher.native_handle(), SIGTERM);
    watcher.join();
    if (!loadFailure.empty()) throw InputError(loadFailure);
    return 0;
}

} // namespace flyover
