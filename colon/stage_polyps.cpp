// The polyps stage: candidates from the lumen's level set (colon/polyp_detect.h), placed on
// the path (arc and anatomical segment), with the study's own rules (the rectal tube's tip,
// the ileocecal valve, tagged stool), and for each one an OST pair centred on it and, with a
// CT, axial, coronal and sagittal crops through it.
//
// Artifacts:
//   polyps/candidates.json   schema flyover.polyps/1: the candidates, best score first
//   polyps/pair_<id>.png     the OST pair at the candidate's place on the path, view 0 on it
//   polyps/axial_<id>.png, coronal_<id>.png, sagittal_<id>.png   CT crops (with a CT)
#include "colon/study_run.h"

#include "colon/polyp_detect.h"
#include "colon/render_settings.h"
#include "colon/render_steps.h"
#include "colon/segment.h"
#include "pipeline/artifact_io.h"
#include "pipeline/camera_json.h"
#include "pipeline/staged_folder.h"
#include "render/camera.h"
#include "render/render_view.h"
#include "volume/ct_slice.h"
#include "volume/error.h"
#include "volume/image.h"
#include "volume/seconds_since.h"

#include <openvdb/tools/Interpolation.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

/// The CT window of the crops: the viewer's default for the colon (air, wall and fat apart).
constexpr double CROP_WINDOW_HU = 1500, CROP_LEVEL_HU = -300;
constexpr double CROP_PIXEL_MM = 0.25;
/// A region's body of mean HU above this is tagged stool, not tissue.
constexpr double TAGGED_STOOL_HU = 250;
/// Candidates this near the rectal tube's tip are the tube's (its open end and shoulder).
constexpr double RECTAL_TUBE_REACH_MM = 30;
/// Candidates this far beyond the terminal ileum's radius from its axis are the valve's lips.
constexpr double ILEOCECAL_REACH_MM = 10;

/// The path point a wall point is reached from: the nearest whose straight way to it stays in
/// the lumen (a touching loop's nearer point is behind a wall); the nearest at all otherwise.
std::size_t pathIndexOf(const Centerline& cl, const openvdb::FloatGrid& sdf, const Vec3d& lumenSideMm)
{
    std::vector<std::size_t> order(cl.points.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return distance(cl.points[a].positionMm, lumenSideMm) < distance(cl.points[b].positionMm, lumenSideMm);
    });
    const double h = sdf.voxelSize()[0];
    openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> sampler(
        sdf.getConstAccessor(), sdf.transform());
    const std::size_t tries = std::min<std::size_t>(order.size(), 64);
    for (std::size_t k = 0; k < tries; ++k) {
        const Vec3d a = cl.points[order[k]].positionMm;
        const double len = distance(a, lumenSideMm);
        const int steps = std::max(1, int(std::ceil(len / (0.5 * h))));
        bool clear = true;
        for (int s = 1; s < steps && clear; ++s) {
            const Vec3d p = a + (lumenSideMm - a) * (double(s) / steps);
            clear = sampler.wsSample(openvdb::Vec3d(p.x, p.y, p.z)) < 0.5 * h;
        }
        if (clear) return order[k];
    }
    return order.empty() ? 0 : order.front();
}

double distanceToPolyline(const std::vector<Vec3d>& line, const Vec3d& p)
{
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i + 1 < line.size(); ++i) best = std::min(best, distanceToSegment(p, line[i], line[i + 1]));
    if (line.size() == 1) best = distance(p, line[0]);
    return best;
}

/// Mean HU of a region's body (its voxels deeper than one voxel, else all of them).
double bodyHu(const openvdb::FloatGrid& hu, const openvdb::FloatGrid& sdf, const PolypRegion& r)
{
    const double h = sdf.voxelSize()[0];
    openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> sampler(
        hu.getConstAccessor(), hu.transform());
    auto acc = sdf.getConstAccessor();
    double deep = 0, all = 0;
    std::size_t nDeep = 0, nAll = 0;
    for (const openvdb::Coord& c : polypBodyVoxels(sdf, r)) {
        const double v = sampler.wsSample(sdf.indexToWorld(c));
        all += v, ++nAll;
        if (acc.getValue(c) > h) deep += v, ++nDeep;
    }
    return nDeep ? deep / double(nDeep) : nAll ? all / double(nAll) : 0.0;
}

/// A CT crop through the candidate, the candidate ringed (radius: half its size + 2 mm).
RgbImage cropImage(const openvdb::FloatGrid& hu, const std::string& plane, const PolypRegion& r, double cropMm)
{
    const Vec3d half{0.5 * cropMm, 0.5 * cropMm, 0.5 * cropMm};
    const SliceImage s = sampleSlice(
        hu, sliceGeometry(plane, r.centroidMm, r.centroidMm - half, r.centroidMm + half, CROP_PIXEL_MM), CROP_WINDOW_HU,
        CROP_LEVEL_HU);
    const SliceGeometry& g = s.geometry;
    RgbImage img;
    img.width = g.width;
    img.height = g.height;
    img.rgb.resize(std::size_t(g.width) * std::size_t(g.height) * 3);
    for (std::size_t i = 0; i < s.gray.size(); ++i) img.rgb[3 * i] = img.rgb[3 * i + 1] = img.rgb[3 * i + 2] = s.gray[i];
    // The ring, in the plane's pixel coordinates.
    const Vec3d d = r.centroidMm - g.originMm;
    const double cx = dot(d, g.colDir) / g.pixelMm, cy = dot(d, g.rowDir) / g.pixelMm;
    const double ringPx = (0.5 * r.sizeMm + 2.0) / g.pixelMm;
    for (int y = 0; y < g.height; ++y)
        for (int x = 0; x < g.width; ++x) {
            const double e = std::abs(std::hypot(x - cx, y - cy) - ringPx);
            if (e > 1.0) continue;
            uint8_t* px = &img.rgb[(std::size_t(y) * std::size_t(g.width) + std::size_t(x)) * 3];
            px[0] = 255, px[1] = 210, px[2] = 0;
        }
    return img;
}

/// The study's rules beyond the wall's shape: "" when the candidate stays.
std::string studyRule(const PolypRegion& r, const Centerline& cl, const openvdb::FloatGrid& sdf,
                      const std::optional<double>& hu)
{
    if (const auto tip = sdf.getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META)) {
        const Vec3d t{tip->value()[0], tip->value()[1], tip->value()[2]};
        if (distance(t, r.centroidMm) < RECTAL_TUBE_REACH_MM) return "at the rectal tube's tip";
    }
    if (!cl.leftOutBranchMm.empty() &&
        distanceToPolyline(cl.leftOutBranchMm, r.centroidMm) < cl.leftOutBranchRadiusMm + ILEOCECAL_REACH_MM)
        return "at the ileocecal valve";
    if (hu && *hu > TAGGED_STOOL_HU) return "tagged (stool: mean HU above 250)";
    return "";
}

/// The pair centred on a candidate: the fly-over cameras of its path point turned so that
/// camera 0 looks straight at it.
std::array<Camera, 2> candidateCameras(const CenterlinePoint& at, const PolypRegion& r, const RenderParams& rp,
                                       double frameRadiusMm)
{
    CenterlinePoint p = at;
    const Vec3d t = normalize(p.tangent);
    Vec3d toward = r.centroidMm - p.positionMm;
    toward = toward - t * dot(toward, t);
    if (length(toward) < 1e-6) toward = r.upDir * -1.0 - t * dot(r.upDir * -1.0, t);
    if (length(toward) > 1e-9) p.normal = normalize(toward) * -1.0;  // camera 0 looks along -normal
    FlyoverParams fp = flyoverParamsOf(rp);
    fp.rollDeg = 0;
    return flyoverCameras(p, fp, frameRadiusMm);
}

json candidateJson(const std::string& id, const PolypRegion& r, std::size_t index, const Centerline& cl,
                   const std::optional<double>& hu)
{
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    return json{{"id", id},
                {"centroid_mm", vec3Json(r.centroidMm)},
                {"apex_mm", vec3Json(r.apexMm)},
                {"up_dir", vec3Json(r.upDir)},
                {"size_mm", r.sizeMm},
                {"height_mm", r.heightMm},
                {"volume_mm3", r.volumeMm3},
                {"area_mm2", r.areaMm2},
                {"morphology", r.morphology},
                {"elongation", r.elongation},
                {"cap_fraction", r.capFraction},
                {"shape_index_mean", r.meanShapeIndex},
                {"curvedness_mean_per_mm", r.meanCurvednessPerMm},
                {"arc_mm", double(index) * step},
                {"centerline_index", index},
                {"segment", index < cl.segment.size() ? cl.segment[index] : std::string()},
                {"score", r.score},
                {"hu_mean", hu ? json(*hu) : json(nullptr)}};
}

} // namespace

json runPolyps(StudyRun& run, Progress* progress)
{
    const auto t0 = std::chrono::steady_clock::now();
    const PolypParams& pp = run.opt.params.polyps;
    const RenderParams& rp = run.opt.params.render;
    StagedFolder out(run.dir, "polyps");
    const bool hasCt = !run.opt.ctPath.empty();
    json list = json::array();
    json report{{"enabled", pp.enabled}};
    if (pp.enabled) {
        reportProgress(progress, 0.05, "polyps: shape of the wall");
        const openvdb::FloatGrid::Ptr sdf = run.sdf();
        PolypDetection d = detectPolyps(*sdf, pp);
        const Centerline& cl = run.renderCenterline();
        openvdb::FloatGrid::Ptr hu;
        if (hasCt && !d.candidates.empty())
            hu = run.state.hu ? run.state.hu : openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(run.path("ct.vdb"), "ct_hu"));
        reportProgress(progress, 0.4, "polyps: candidates on the path");
        struct Kept {
            PolypRegion region;
            std::size_t index;
            std::optional<double> hu;
        };
        std::vector<Kept> kept;
        std::map<std::string, std::size_t> droppedBy = d.droppedBy;
        for (const PolypRegion& r : d.candidates) {
            std::optional<double> meanHu;
            if (hu) meanHu = bodyHu(*hu, *sdf, r);
            const std::string rule = studyRule(r, cl, *sdf, meanHu);
            if (!rule.empty()) {
                ++droppedBy[rule];
                continue;
            }
            if (int(kept.size()) >= pp.maxCandidates) {
                ++droppedBy["beyond polyps.max_candidates"];
                continue;
            }
            kept.push_back({r, cl.points.empty() ? 0 : pathIndexOf(cl, *sdf, r.apexMm + r.upDir * 1.0), meanHu});
        }
        const RenderInputs* in = nullptr;
        if (pp.images && !kept.empty() && !cl.points.empty()) in = &run.renderInputs();
        for (std::size_t k = 0; k < kept.size(); ++k) {
            const Kept& c = kept[k];
            const std::string id = "c" + std::to_string(k + 1);
            json j = candidateJson(id, c.region, c.index, cl, c.hu);
            json images = json::object();
            if (in) {
                const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
                const auto cams = candidateCameras(cl.points[c.index], c.region, rp, in->frameRadii[c.index]);
                RgbImage pair;
                renderPair(*in->scene, cams[0], cams[1], loopLocal(frameOptionsOf(rp), *in, rp, c.index, step), pair);
                const std::string pairFile = "pair_" + id + ".png";
                writePng(out.path(pairFile), pair);
                images["pair"] = pairFile;
                j["pose"] = json{{"centerline_index", c.index},
                                 {"arc_mm", double(c.index) * step},
                                 {"view", 0},
                                 {"cameras", json::array({cameraJson(cams[0]), cameraJson(cams[1])})}};
                if (hu)
                    for (const char* plane : {"axial", "coronal", "sagittal"}) {
                        const std::string file = std::string(plane) + "_" + id + ".png";
                        writePng(out.path(file), cropImage(*hu, plane, c.region, pp.cropMm));
                        images[plane] = file;
                    }
            } else {
                j["pose"] = nullptr;
            }
            j["images"] = images;
            list.push_back(j);
            reportProgress(progress, 0.5 + 0.5 * double(k + 1) / double(kept.size()), "polyps: images");
        }
        json dropped = json::object();
        for (const auto& [rule, n] : droppedBy) dropped[rule] = n;
        report = json{{"enabled", true},
                      {"candidates", list.size()},
                      {"regions", d.regions},
                      {"surface_voxels", d.surfaceVoxels},
                      {"seed_voxels", d.seedVoxels},
                      {"dropped_by", dropped},
                      {"detect_seconds", d.seconds}};
    }
    writeJson(out.path("candidates.json"),
              json{{"schema", "flyover.polyps/1"},
                   {"world_frame", WORLD_FRAME},
                   {"has_ct", hasCt},
                   {"method", "shape index and curvedness of the lumen's level set (docs/method.md, Polyp candidates)"},
                   {"dropped_by", report.value("dropped_by", json::object())},
                   {"candidates", list}});
    out.commit();
    report["seconds"] = secondsSince(t0);
    return report;
}

} // namespace flyover
