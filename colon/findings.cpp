#include "colon/findings.h"

#include "colon/anatomy_segments.h"
#include "pipeline/json_io.h"
#include "volume/error.h"
#include "volume/image.h"

#include <algorithm>
#include <cmath>
#include <set>

using nlohmann::json;

namespace flyover {

namespace {

const json& field(const json& j, const char* name, const std::string& where)
{
    if (!j.contains(name)) throw InputError(where + ": no \"" + name + "\"");
    return j[name];
}

std::string text(const json& j, const char* name, const std::string& where)
{
    const json& v = field(j, name, where);
    if (!v.is_string()) throw InputError(where + ": \"" + name + "\" must be a string");
    return v.get<std::string>();
}

double number(const json& j, const char* name, const std::string& where, double lo, double hi)
{
    const json& v = field(j, name, where);
    if (!v.is_number()) throw InputError(where + ": \"" + name + "\" must be a number");
    const double x = v.get<double>();
    if (!std::isfinite(x) || x < lo || x > hi)
        throw InputError(where + ": \"" + name + "\" = " + v.dump() + " is outside [" + json(lo).dump() + ", " +
                         json(hi).dump() + "]");
    return x;
}

Vec3d point(const json& j, const char* name, const std::string& where)
{
    const json& v = field(j, name, where);
    if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() || !v[2].is_number())
        throw InputError(where + ": \"" + name + "\" must be [x, y, z] (LPS mm)");
    const Vec3d p{v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
        throw InputError(where + ": \"" + name + "\" must be finite");
    return p;
}

std::string oneOf(const json& j, const char* name, const std::string& where, bool (*ok)(const std::string&),
                  const char* options)
{
    const std::string v = text(j, name, where);
    if (!ok(v)) throw InputError(where + ": \"" + name + "\" = \"" + v.substr(0, 40) + "\" is not " + options);
    return v;
}

/// An image file name of polyps/: a plain name, no folder, no "..".
bool plainFileName(const std::string& s)
{
    if (s.empty() || s.size() > 200 || s.find('/') != std::string::npos || s.find('\\') != std::string::npos ||
        s.find("..") != std::string::npos || s[0] == '.')
        return false;
    return true;
}

constexpr double MAX_MM = 1e5;

} // namespace

bool isMorphology(const std::string& m) { return m == "sessile" || m == "pedunculated" || m == "flat"; }

bool isSegmentName(const std::string& s)
{
    if (s.empty()) return true;
    const auto& names = anatomySegmentNames();
    return std::find(names.begin(), names.end(), s) != names.end();
}

PolypCandidate candidateFromJson(const json& j, const std::string& where)
{
    if (!j.is_object()) throw InputError(where + ": must be an object");
    PolypCandidate c;
    c.id = text(j, "id", where);
    const std::string at = where + " (" + c.id.substr(0, 40) + ")";
    c.centroidMm = point(j, "centroid_mm", at);
    c.sizeMm = number(j, "size_mm", at, 0, MAX_MM);
    c.heightMm = j.contains("height_mm") ? number(j, "height_mm", at, 0, MAX_MM) : 0.0;
    c.volumeMm3 = j.contains("volume_mm3") ? number(j, "volume_mm3", at, 0, 1e12) : 0.0;
    c.morphology = oneOf(j, "morphology", at, isMorphology, "sessile, pedunculated or flat");
    c.arcMm = number(j, "arc_mm", at, -MAX_MM, MAX_MM);
    c.segment = oneOf(j, "segment", at, isSegmentName, "an anatomical segment");
    c.score = number(j, "score", at, 0, 1);
    if (j.contains("hu_mean") && !j["hu_mean"].is_null()) c.huMean = number(j, "hu_mean", at, -1e5, 1e5);
    c.pose = j.value("pose", json());
    if (j.contains("images") && !j["images"].is_null()) {
        if (!j["images"].is_object()) throw InputError(at + ": \"images\" must be an object of file names");
        for (auto it = j["images"].begin(); it != j["images"].end(); ++it) {
            if (it.value().is_null()) continue;
            if (!it.value().is_string() || !plainFileName(it.value().get<std::string>()))
                throw InputError(at + ": images." + it.key() + " must be a file name in polyps/");
            c.images[it.key()] = it.value().get<std::string>();
        }
    }
    return c;
}

json candidateToJson(const PolypCandidate& c)
{
    json j{{"id", c.id},         {"centroid_mm", vec3Json(c.centroidMm)},
           {"size_mm", c.sizeMm}, {"height_mm", c.heightMm},
           {"volume_mm3", c.volumeMm3}, {"morphology", c.morphology},
           {"arc_mm", c.arcMm},   {"segment", c.segment},
           {"score", c.score},    {"pose", c.pose}};
    if (c.huMean) j["hu_mean"] = *c.huMean;
    json images = json::object();
    for (const auto& [k, v] : c.images) images[k] = v;
    j["images"] = images;
    return j;
}

std::vector<PolypCandidate> readCandidates(const std::string& path)
{
    const json j = readJson(path);
    if (!j.is_object() || j.value("schema", "") != "flyover.polyps/1")
        throw InputError(path + ": not a candidates file (schema \"flyover.polyps/1\" expected)");
    if (!j.contains("candidates") || !j["candidates"].is_array())
        throw InputError(path + ": no \"candidates\" list");
    std::vector<PolypCandidate> out;
    std::set<std::string> ids;
    for (std::size_t k = 0; k < j["candidates"].size(); ++k) {
        out.push_back(candidateFromJson(j["candidates"][k], path + ": candidates[" + std::to_string(k) + "]"));
        if (!ids.insert(out.back().id).second) throw InputError(path + ": candidate id \"" + out.back().id + "\" twice");
    }
    std::stable_sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
    return out;
}

Finding findingFromJson(const json& j, const std::string& where)
{
    static const std::set<std::string> known = {"id",     "source", "candidate_id", "status",     "size_mm",
                                                "position_mm", "arc_mm", "segment",      "morphology", "note"};
    if (!j.is_object()) throw InputError(where + ": must be an object");
    for (auto it = j.begin(); it != j.end(); ++it)
        if (!known.count(it.key())) throw InputError(where + ": unknown field \"" + it.key().substr(0, 40) + "\"");
    Finding f;
    f.id = text(j, "id", where);
    const std::string at = where + " (" + f.id.substr(0, 40) + ")";
    if (f.id.empty() || f.id.size() > 40) throw InputError(at + ": \"id\" must be 1..40 characters");
    f.source = oneOf(j, "source", at, [](const std::string& s) { return s == "candidate" || s == "hand"; },
                     "candidate or hand");
    if (f.source == "candidate") f.candidateId = text(j, "candidate_id", at);
    else if (j.contains("candidate_id") && !j["candidate_id"].is_null())
        throw InputError(at + ": a hand finding has no \"candidate_id\"");
    f.status = oneOf(j, "status", at, [](const std::string& s) { return s == "accepted" || s == "rejected"; },
                     "accepted or rejected");
    f.sizeMm = number(j, "size_mm", at, 0, MAX_MM);
    f.positionMm = point(j, "position_mm", at);
    f.arcMm = number(j, "arc_mm", at, -MAX_MM, MAX_MM);
    f.segment = oneOf(j, "segment", at, isSegmentName, "an anatomical segment");
    f.morphology = oneOf(j, "morphology", at, isMorphology, "sessile, pedunculated or flat");
    if (j.contains("note")) f.note = text(j, "note", at);
    return f;
}

json findingToJson(const Finding& f)
{
    json j{{"id", f.id},
           {"source", f.source},
           {"status", f.status},
           {"size_mm", f.sizeMm},
           {"position_mm", vec3Json(f.positionMm)},
           {"arc_mm", f.arcMm},
           {"segment", f.segment},
           {"morphology", f.morphology}};
    if (f.source == "candidate") j["candidate_id"] = f.candidateId;
    if (!f.note.empty()) j["note"] = f.note;
    return j;
}

std::vector<Finding> readFindings(const std::string& path)
{
    const json j = readJson(path);
    if (!j.is_object() || j.value("schema", "") != "flyover.findings/1")
        throw InputError(path + ": not a findings file (schema \"flyover.findings/1\" expected); move it away to "
                                "start afresh");
    if (!j.contains("findings") || !j["findings"].is_array()) throw InputError(path + ": no \"findings\" list");
    std::vector<Finding> out;
    std::set<std::string> ids, candidates;
    for (std::size_t k = 0; k < j["findings"].size(); ++k) {
        Finding f = findingFromJson(j["findings"][k], path + ": findings[" + std::to_string(k) + "]");
        if (!ids.insert(f.id).second) throw InputError(path + ": finding id \"" + f.id + "\" twice");
        if (f.source == "candidate" && !candidates.insert(f.candidateId).second)
            throw InputError(path + ": candidate \"" + f.candidateId + "\" reviewed twice");
        out.push_back(std::move(f));
    }
    return out;
}

json findingsFileJson(const std::vector<Finding>& findings)
{
    json list = json::array();
    for (const Finding& f : findings) list.push_back(findingToJson(f));
    return json{{"schema", "flyover.findings/1"}, {"world_frame", WORLD_FRAME}, {"findings", list}};
}

void writeFindings(const std::string& path, const std::vector<Finding>& findings)
{
    writeJson(path, findingsFileJson(findings));
}

} // namespace flyover
