#include "view/findings_routes.h"

#include "view/finding_store.h"
#include "view/http_request.h"
#include "view/view_study.h"
#include "volume/image.h"

#include <cmath>

using nlohmann::json;

namespace flyover {

namespace {

using namespace http;

constexpr double MIN_SIZE_MM = 0.1, MAX_SIZE_MM = 200.0;
constexpr double MAX_HAND_DISTANCE_MM = 150.0;  ///< a hand finding lies this close to the path at most

std::string jsonText(const json& body, const std::string& name, std::size_t maxBytes)
{
    if (!body.contains(name) || !body[name].is_string()) throw HttpError(400, name + ": must be a string");
    const std::string v = body[name].get<std::string>();
    if (v.size() > maxBytes) throw HttpError(422, name + ": longer than " + std::to_string(maxBytes) + " bytes");
    return v;
}

std::optional<std::string> optionalText(const json& body, const std::string& name, std::size_t maxBytes)
{
    if (!body.contains(name) || body[name].is_null()) return std::nullopt;
    return jsonText(body, name, maxBytes);
}

/// size_mm of the body: -1 when absent (keep), else within [MIN_SIZE_MM, MAX_SIZE_MM].
double sizeOf(const json& body, bool required)
{
    if (required && (!body.contains("size_mm") || body["size_mm"].is_null())) throw HttpError(400, "size_mm: missing");
    return jsonNumber(body, "size_mm", -1.0, MIN_SIZE_MM, MAX_SIZE_MM);
}

Vec3d pointOf(const json& body, const std::string& name)
{
    if (!body.contains(name)) throw HttpError(400, name + ": missing");
    const json& v = body[name];
    if (!v.is_array() || v.size() != 3) throw HttpError(400, name + ": must be [x, y, z] (LPS mm)");
    double c[3];
    for (std::size_t k = 0; k < 3; ++k) {
        if (!v[k].is_number()) throw HttpError(400, name + ": must be [x, y, z] (LPS mm)");
        c[k] = v[k].get<double>();
        if (!std::isfinite(c[k]) || std::abs(c[k]) > 1e5) throw HttpError(422, name + ": must be finite, |x| <= 1e5");
    }
    return Vec3d{c[0], c[1], c[2]};
}

void postReview(const httplib::Request& req, httplib::Response& res, FindingStore& store)
{
    const json body = parseBody(req);
    onlyFields(body, {"candidate_id", "status", "size_mm", "note"});
    const std::string id = jsonText(body, "candidate_id", 40);
    if (!body.contains("status")) throw HttpError(400, "status: missing");
    const std::string status = jsonChoice(body, "status", "", {"accepted", "rejected"});
    const json out = store.review(id, status, sizeOf(body, false), optionalText(body, "note", 2000));
    sendJson(res, out, out["created"].get<bool>() ? 201 : 200);
}

void postEdit(const httplib::Request& req, httplib::Response& res, FindingStore& store)
{
    const json body = parseBody(req);
    onlyFields(body, {"id", "size_mm", "status", "note"});
    const std::string id = jsonText(body, "id", 40);
    std::optional<std::string> status;
    if (body.contains("status") && !body["status"].is_null())
        status = jsonChoice(body, "status", "", {"accepted", "rejected"});
    sendJson(res, store.edit(id, sizeOf(body, false), status, optionalText(body, "note", 2000)));
}

void postHand(const httplib::Request& req, httplib::Response& res, FindingStore& store, const ViewStudy& study)
{
    const json body = parseBody(req);
    onlyFields(body, {"position_mm", "size_mm", "morphology", "note"});
    const Vec3d p = pointOf(body, "position_mm");
    const double size = sizeOf(body, true);
    const std::string morphology = jsonChoice(body, "morphology", "sessile", {"sessile", "pedunculated", "flat"});
    const std::string note = optionalText(body, "note", 2000).value_or("");
    const Centerline& cl = study.centerline();
    if (cl.points.empty()) throw HttpError(409, "the study has no centerline");
    const std::size_t i = study.nearestIndex(p);
    const double away = length(cl.points[i].positionMm - p);
    if (away > MAX_HAND_DISTANCE_MM)
        throw HttpError(422, "position_mm: " + Query::shortNumber(away) + " mm from the centerline (at most " +
                                 Query::shortNumber(MAX_HAND_DISTANCE_MM) + ")");
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    const std::string segment = i < cl.segment.size() ? cl.segment[i] : "";
    sendJson(res, store.addByHand(p, double(i) * step, segment, size, morphology, note), 201);
}

} // namespace

void serveFindings(const httplib::Request& req, httplib::Response& res, FindingStore& store, const ViewStudy& study)
{
    const std::string& path = req.path;
    const std::string& method = req.method;
    try {
        if (path == "/api/findings") {
            if (method == "GET" || method == "HEAD") {
                Query q(req, {});
                json j = store.list();
                j["world_frame"] = WORLD_FRAME;
                sendJson(res, j);
            } else if (method == "DELETE") {
                Query q(req, {"id"});
                if (!q.has("id")) throw HttpError(400, "id: missing");
                if (!store.remove(q.text("id")))
                    throw HttpError(404, "no finding with id '" + q.text("id").substr(0, 40) + "'");
                sendJson(res, json{{"deleted", q.text("id")}});
            } else {
                throw HttpError(405, method + " /api/findings: GET or DELETE");
            }
            return;
        }
        void (*post)(const httplib::Request&, httplib::Response&, FindingStore&) =
            path == "/api/findings/review" ? postReview : path == "/api/findings/edit" ? postEdit : nullptr;
        if (!post && path != "/api/findings/hand") throw HttpError(404, "no such path: " + path.substr(0, 80));
        if (method != "POST") throw HttpError(405, method + " " + path + ": only POST");
        Query q(req, {});
        if (post) post(req, res, store);
        else postHand(req, res, store, study);
    } catch (const FindingRefused& e) {
        throw HttpError(e.status, e.what());
    }
}

} // namespace flyover
