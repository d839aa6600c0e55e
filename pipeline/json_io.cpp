#include "pipeline/json_io.h"

#include "pipeline/atomic_write.h"
#include "volume/error.h"
#include "volume/image.h"

#include <algorithm>
#include <fstream>

namespace flyover {

void writeJson(const std::string& path, const nlohmann::json& j)
{
    writeAtomically(path, [&](const std::string& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out << j.dump(2) << "\n";
        if (!out.flush()) throw InputError(path + ": cannot write");
    });
}

nlohmann::json readJson(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open for reading");
    nlohmann::json j = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) throw InputError(path + ": not valid JSON");
    return j;
}

nlohmann::json centerlineToJson(const Centerline& c)
{
    using nlohmann::json;
    json pos = json::array(), tan = json::array(), nor = json::array(), rad = json::array(),
         bridged = json::array();
    auto v3 = [](const Vec3d& v) { return json::array({v.x, v.y, v.z}); };
    for (const auto& p : c.points) {
        pos.push_back(v3(p.positionMm));
        tan.push_back(v3(p.tangent));
        nor.push_back(v3(p.normal));
        rad.push_back(p.radiusMm);
        bridged.push_back(p.bridged);
    }
    json out{{"schema", "flyover.centerline/1"},
             {"world_frame", WORLD_FRAME},
             {"units", "mm"},
             {"order", "rectum to cecum"},
             {"step_mm", c.stepMm},
             {"length_mm", c.lengthMm()},
             {"point_count", c.points.size()},
             {"position_mm", pos},
             {"tangent", tan},
             {"normal", nor},
             {"radius_mm", rad},
             {"bridged", bridged}};
    if (!c.leftOutBranchMm.empty()) {  // only then: other files stay byte for byte
        json axis = json::array();
        for (const Vec3d& p : c.leftOutBranchMm) axis.push_back(v3(p));
        out["left_out_branch"] = json{{"meaning", "a narrow tube at the lumen's far end that the path leaves out "
                                                  "(the terminal ileum off the cecum): its axis past the mouth and "
                                                  "its radius; its wall is not counted in coverage"},
                                      {"axis_mm", axis},
                                      {"radius_mm", c.leftOutBranchRadiusMm}};
    }
    if (!c.segment.empty()) {  // only on a labelled path (colon/anatomy_segments.h)
        out["segment"] = c.segment;
        json landmarks = json::object();
        for (const CenterlineLandmark& l : c.landmarks)
            landmarks[l.name] = json{{"index", l.index}, {"arc_mm", l.arcMm}, {"position_mm", v3(l.positionMm)}};
        out["landmarks"] = landmarks;
        out["segments_frame"] = c.segmentsFrame;
        if (!c.segmentsFrameReason.empty()) out["segments_frame_reason"] = c.segmentsFrameReason;
    }
    return out;
}

Centerline centerlineFromJson(const nlohmann::json& j, const std::string& source)
{
    auto fail = [&](const std::string& what) -> void { throw InputError(source + ": " + what); };
    if (!j.is_object() || j.value("schema", "") != "flyover.centerline/1")
        fail("not a flyover centerline (schema flyover.centerline/1)");
    if (j.value("world_frame", "") != WORLD_FRAME) fail("centerline world frame is not LPS");
    Centerline c;
    c.stepMm = j.value("step_mm", 1.0);
    const auto& pos = j.at("position_mm");
    const auto& tan = j.at("tangent");
    const auto& nor = j.at("normal");
    const auto& rad = j.at("radius_mm");
    const auto& br = j.at("bridged");
    const std::size_t n = pos.size();
    if (tan.size() != n || nor.size() != n || rad.size() != n || br.size() != n)
        fail("centerline arrays differ in length");
    auto v3 = [&](const nlohmann::json& a) {
        if (!a.is_array() || a.size() != 3) fail("expected [x,y,z]");
        return Vec3d{a[0].get<double>(), a[1].get<double>(), a[2].get<double>()};
    };
    c.points.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        c.points[i].positionMm = v3(pos[i]);
        c.points[i].tangent = v3(tan[i]);
        c.points[i].normal = v3(nor[i]);
        c.points[i].radiusMm = rad[i].get<double>();
        c.points[i].bridged = br[i].get<bool>();
    }
    if (j.contains("left_out_branch")) {
        const auto& b = j.at("left_out_branch");
        if (!b.is_object() || !b.contains("axis_mm") || !b.at("axis_mm").is_array())
            fail("left_out_branch: expected an object with axis_mm");
        for (const auto& a : b.at("axis_mm")) c.leftOutBranchMm.push_back(v3(a));
        c.leftOutBranchRadiusMm = b.value("radius_mm", 0.0);
        if (!(c.leftOutBranchRadiusMm >= 0) || !std::isfinite(c.leftOutBranchRadiusMm))
            fail("left_out_branch: radius_mm must be a finite value >= 0");
    }
    // Anatomical segments: optional (files written before them load without).
    if (j.contains("segment")) {
        const auto& seg = j.at("segment");
        if (!seg.is_array() || seg.size() != n) fail("segment: expected one string per point");
        for (const auto& s : seg) {
            if (!s.is_string()) fail("segment: expected one string per point");
            c.segment.push_back(s.get<std::string>());
        }
        c.segmentsFrame = j.value("segments_frame", "");
        c.segmentsFrameReason = j.value("segments_frame_reason", "");
    }
    if (j.contains("landmarks")) {
        const auto& lm = j.at("landmarks");
        if (!lm.is_object()) fail("landmarks: expected an object");
        for (auto it = lm.begin(); it != lm.end(); ++it) {
            const auto& l = it.value();
            if (!l.is_object() || !l.contains("index") || !l.at("index").is_number_unsigned() ||
                l.at("index").get<std::size_t>() >= n)
                fail("landmarks: " + it.key() + ": expected an index of a point");
            CenterlineLandmark m;
            m.name = it.key();
            m.index = l.at("index").get<std::size_t>();
            m.arcMm = l.value("arc_mm", double(m.index) * c.stepMm);
            m.positionMm = l.contains("position_mm") ? v3(l.at("position_mm")) : c.points[m.index].positionMm;
            c.landmarks.push_back(m);
        }
        // Path order, as written (a JSON object's keys come back sorted).
        std::stable_sort(c.landmarks.begin(), c.landmarks.end(),
                         [](const CenterlineLandmark& a, const CenterlineLandmark& b) { return a.index < b.index; });
    }
    return c;
}

} // namespace flyover
