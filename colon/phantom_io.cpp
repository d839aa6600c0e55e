#include "colon/phantom_io.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"
#include "volume/image_io.h"

#include <cmath>
#include <sstream>
#include <string>

namespace flyover {

using nlohmann::json;

namespace {
json v3(const Vec3d& v) { return json::array({v.x, v.y, v.z}); }
Vec3d v3(const json& j) { return {j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()}; }
} // namespace

/// The variants' truth, only for the variants asked (the default file is unchanged).
void addVariantTruth(json& out, const Phantom& ph, const PhantomParams& params)
{
    const PhantomTruth& t = ph.truth;
    const bool anyNew = params.touching > 0 || params.redundant || params.rectalTube;
    const bool stored = params.orientation != "LPS";
    if (anyNew || params.fluid || params.collapse || params.stricture || params.prone || stored || params.ilealReflux ||
        params.wideRectum || params.polypDiametersMm) {
        double lengthMm = 0;
        for (std::size_t i = 1; i < t.centerlineMm.size(); ++i) lengthMm += distance(t.centerlineMm[i - 1], t.centerlineMm[i]);
        out["variants"] = json{{"touching", params.touching}, {"redundant", params.redundant},
                               {"rectal_tube", params.rectalTube}, {"fluid", params.fluid},
                               {"collapse", params.collapse}, {"stricture", params.stricture}};
        if (params.prone) out["variants"]["prone"] = true;
        if (params.ilealReflux) out["variants"]["ileal_reflux"] = true;
        if (params.wideRectum) out["variants"]["wide_rectum"] = true;
        if (params.polypDiametersMm) out["variants"]["polyp_diameters_mm"] = *params.polypDiametersMm;
        if (stored) out["variants"]["orientation"] = params.orientation;
        out["centerline"]["length_mm"] = lengthMm;
    }
    if (params.collapse) {
        json c = json::array();
        for (const auto& s : t.collapsed) c.push_back(json{{"arc_start_mm", s.arcStartMm}, {"arc_end_mm", s.arcEndMm}});
        out["collapsed"] = c;
    }
    if (params.stricture) {
        json c = json::array();
        for (const auto& s : t.strictures)
            c.push_back(json{{"arc_start_mm", s.arcStartMm}, {"arc_end_mm", s.arcEndMm}, {"min_radius_mm", s.minRadiusMm}});
        out["strictures"] = c;
    }
    if (params.fluid) {
        json f = json::array();
        for (const auto& p : t.fluidPools) {
            f.push_back(json{{"arc_start_mm", p.arcStartMm}, {"arc_end_mm", p.arcEndMm},
                             {"level_y_mm", p.levelYMm}, {"hu", p.hu}});
            if (params.prone) f.back()["gravity_lps"] = json::array({0.0, p.downY, 0.0});
        }
        out["fluid_pools"] = f;
        out["fluid_volume_ml"] = t.fluidVolumeMl;
    }
    if (params.touching > 0) {
        json c = json::array();
        for (const auto& k : t.contacts)
            c.push_back(json{{"position_mm", v3(k.positionMm)}, {"width_mm", k.widthMm},
                             {"arc_a_mm", k.arcAMm}, {"arc_b_mm", k.arcBMm}, {"axis", v3(k.axis)},
                             {"half_length_a_mm", k.halfLengthAMm}, {"half_length_b_mm", k.halfLengthBMm}});
        out["contacts"] = c;
    }
    if (t.hasRectalTube) {
        const PhantomRectalTube& tube = t.rectalTube;
        json axis = json::array();
        for (const auto& p : tube.axisMm) axis.push_back(v3(p));
        out["rectal_tube"] = json{{"axis_mm", axis},
                                  {"axis_order", "outer end (outside the body) to tip (in the rectum)"},
                                  {"inner_radius_mm", tube.innerRadiusMm},
                                  {"outer_radius_mm", tube.outerRadiusMm},
                                  {"wall_hu", tube.wallHu},
                                  {"tip_mm", v3(tube.tipMm())},
                                  {"lumen_in_mask_volume_ml", t.tubeLumenVolumeMl}};
    }
    if (!t.ileumMm.empty()) {
        json axis = json::array();
        for (const auto& p : t.ileumMm) axis.push_back(v3(p));
        out["ileum"] = json{{"axis_mm", axis},
                            {"axis_order", "from inside the cecum at the ileocecal valve to the blind end"},
                            {"radius_mm", t.ileumRadiusMm},
                            {"valve_colon_arc_mm", t.ileumValveArcMm},
                            {"lumen_volume_ml", t.ileumLumenVolumeMl},
                            {"in_truth_mask", false}};
    }
    if (anyNew) out["colon_lumen_volume_ml"] = t.colonLumenVolumeMl;
}

json phantomTruthToJson(const Phantom& ph, const PhantomParams& params)
{
    const auto& g = ph.ct.geometry;
    json pos = json::array();
    for (const auto& p : ph.truth.centerlineMm) pos.push_back(v3(p));
    json polyps = json::array();
    for (const auto& p : ph.truth.polyps)
        polyps.push_back(json{{"center_mm", v3(p.centerMm)},
                              {"radius_mm", p.radiusMm},
                              {"arc_mm", p.arcMm},
                              {"outward_dir", v3(p.outwardDir)},
                              {"between_folds", p.betweenFolds}});
    json direction = json::array();
    for (int r = 0; r < 3; ++r) direction.push_back({g.direction[r][0], g.direction[r][1], g.direction[r][2]});
    json out{
        {"schema", "flyover.phantom-truth/1"},
        {"world_frame", WORLD_FRAME},
        {"units", "mm"},
        {"convention",
         "LPS world millimetres (x: patient left, y: posterior, z: superior), as in DICOM and ITK; "
         "voxel (i,j,k) centre = origin + direction * (spacing * (i,j,k)); the NIfTI affine holds "
         "the same geometry converted to RAS"},
        {"size", phantomSizeName(params.size)},
        {"seed", params.seed},
        {"noise_hu", params.noiseHu},
        {"image",
         json{{"size", g.size}, {"spacing_mm", v3(g.spacingMm)}, {"origin_mm", v3(g.originMm)},
              {"direction_rows", direction}}},
        {"centerline",
         json{{"order", "rectum to cecum"},
              {"position_mm", pos},
              {"radius_mm", ph.truth.radiusMm},
              {"segment", ph.truth.segment}}},
        {"polyps", polyps},
        {"lumen_volume_ml", ph.truth.lumenVolumeMl}};
    addVariantTruth(out, ph, params);
    return out;
}

PhantomTruth phantomTruthFromJson(const json& j, const std::string& source)
{
    if (j.value("schema", "") != "flyover.phantom-truth/1")
        throw InputError(source + ": not a flyover phantom truth file (schema flyover.phantom-truth/1)");
    PhantomTruth t;
    const auto& c = j.at("centerline");
    for (const auto& p : c.at("position_mm")) t.centerlineMm.push_back(v3(p));
    t.radiusMm = c.at("radius_mm").get<std::vector<double>>();
    t.segment = c.at("segment").get<std::vector<std::string>>();
    for (const auto& p : j.at("polyps")) {
        PhantomPolyp q;
        q.centerMm = v3(p.at("center_mm"));
        q.radiusMm = p.at("radius_mm").get<double>();
        q.arcMm = p.at("arc_mm").get<double>();
        q.outwardDir = v3(p.at("outward_dir"));
        q.betweenFolds = p.at("between_folds").get<bool>();
        t.polyps.push_back(q);
    }
    t.lumenVolumeMl = j.at("lumen_volume_ml").get<double>();
    t.colonLumenVolumeMl = j.value("colon_lumen_volume_ml", t.lumenVolumeMl);
    t.fluidVolumeMl = j.value("fluid_volume_ml", 0.0);
    for (const auto& c : j.value("collapsed", json::array()))
        t.collapsed.push_back({c.at("arc_start_mm").get<double>(), c.at("arc_end_mm").get<double>()});
    for (const auto& c : j.value("strictures", json::array()))
        t.strictures.push_back({c.at("arc_start_mm").get<double>(), c.at("arc_end_mm").get<double>(),
                                c.at("min_radius_mm").get<double>()});
    for (const auto& p : j.value("fluid_pools", json::array()))
        t.fluidPools.push_back({p.at("arc_start_mm").get<double>(), p.at("arc_end_mm").get<double>(),
                                p.at("level_y_mm").get<double>(), p.at("hu").get<double>(),
                                p.contains("gravity_lps") ? p.at("gravity_lps").at(1).get<double>() : 1.0});
    if (j.contains("ileum")) {
        const json& il = j.at("ileum");
        for (const auto& p : il.at("axis_mm")) t.ileumMm.push_back(v3(p));
        t.ileumRadiusMm = il.at("radius_mm").get<double>();
        t.ileumValveArcMm = il.at("valve_colon_arc_mm").get<double>();
        t.ileumLumenVolumeMl = il.value("lumen_volume_ml", 0.0);
    }
    for (const auto& c : j.value("contacts", json::array())) {
        PhantomContact k;
        k.positionMm = v3(c.at("position_mm"));
        k.widthMm = c.at("width_mm").get<double>();
        k.arcAMm = c.at("arc_a_mm").get<double>();
        k.arcBMm = c.at("arc_b_mm").get<double>();
        k.axis = v3(c.at("axis"));
        k.halfLengthAMm = c.at("half_length_a_mm").get<double>();
        k.halfLengthBMm = c.at("half_length_b_mm").get<double>();
        t.contacts.push_back(k);
    }
    if (j.contains("rectal_tube")) {
        const auto& r = j.at("rectal_tube");
        t.hasRectalTube = true;
        for (const auto& p : r.at("axis_mm")) t.rectalTube.axisMm.push_back(v3(p));
        t.rectalTube.innerRadiusMm = r.at("inner_radius_mm").get<double>();
        t.rectalTube.outerRadiusMm = r.at("outer_radius_mm").get<double>();
        t.rectalTube.wallHu = r.at("wall_hu").get<double>();
        t.tubeLumenVolumeMl = r.at("lumen_in_mask_volume_ml").get<double>();
    }
    return t;
}

Vec3d parsePhantomSpacing(const std::string& text)
{
    Vec3d out;
    std::size_t start = 0;
    for (int c = 0; c < 3; ++c) {
        const std::size_t end = c < 2 ? text.find(',', start) : text.size();
        const std::string part = end == std::string::npos ? std::string() : text.substr(start, end - start);
        std::size_t used = 0;
        double v = 0;
        try {
            v = std::stod(part, &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (part.empty() || used != part.size() || !std::isfinite(v))
            throw ParameterError("--spacing: expected three numbers SX,SY,SZ in mm (e.g. 0.8,0.8,1.25), got \"" +
                                 text + "\"");
        out[c] = v;
        start = end + 1;
    }
    for (int c = 0; c < 3; ++c)
        if (out[c] < PHANTOM_MIN_SPACING_MM || out[c] > PHANTOM_MAX_SPACING_MM) {
            std::ostringstream msg;
            msg << "--spacing: each voxel size must be in [" << PHANTOM_MIN_SPACING_MM << ", "
                << PHANTOM_MAX_SPACING_MM << "] mm, got \"" << text << "\"";
            throw ParameterError(msg.str());
        }
    return out;
}

void writePhantom(const Phantom& phantom, const PhantomParams& params, const std::string& ctPath,
                  const std::string& truthPath, const std::string& maskPath)
{
    writeImage(phantom.ct, ctPath);
    if (!truthPath.empty()) writeJson(truthPath, phantomTruthToJson(phantom, params));
    if (!maskPath.empty()) writeImage(phantom.truthLumen, maskPath);
}

} // namespace flyover
