#include "pipeline/phantom_io.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"
#include "volume/image_io.h"

namespace flyover {

using nlohmann::json;

namespace {
json v3(const Vec3d& v) { return json::array({v.x, v.y, v.z}); }
Vec3d v3(const json& j) { return {j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()}; }
} // namespace

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
    return json{
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
    return t;
}

void writePhantom(const Phantom& phantom, const PhantomParams& params, const std::string& ctPath,
                  const std::string& truthPath, const std::string& maskPath)
{
    writeImage(phantom.ct, ctPath);
    if (!truthPath.empty()) writeJson(truthPath, phantomTruthToJson(phantom, params));
    if (!maskPath.empty()) writeImage(phantom.truthLumen, maskPath);
}

} // namespace flyover
