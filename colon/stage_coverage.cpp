// The colon's coverage step: which share of the wall the fly-over and the fly-through show,
// the missed regions, review views of what the fly-over missed, and the seen share per
// anatomical segment (coverage/ and review/).

#include "colon/anatomy_segments.h"
#include "colon/render_settings.h"
#include "colon/render_steps.h"
#include "colon/study_run.h"
#include "pipeline/artifact_io.h"
#include "pipeline/render_output.h"
#include "render/coverage.h"
#include "render/flyover_path.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "render/review.h"
#include "volume/error.h"
#include "volume/seconds_since.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

using nlohmann::json;

namespace flyover {

namespace {

using Clock = std::chrono::steady_clock;

json missedRegionsJson(const std::vector<MissedRegion>& regions)
{
    json out = json::array();
    for (const MissedRegion& r : regions)
        out.push_back(json{{"area_mm2", r.areaMm2},
                           {"centroid_mm", vec3Json(r.centroidMm)},
                           {"triangles", r.triangles},
                           {"nearest_centerline_index", r.nearestCenterlineIndex},
                           {"arc_mm", r.arcMm},
                           {"distance_to_centerline_mm", r.distanceToCenterlineMm}});
    return out;
}

json methodJson(const MethodCoverage& m, double minRegionMm2)
{
    return json{{"fraction", m.fraction},
                {"seen_area_mm2", m.seenAreaMm2},
                {"missed_regions_min_area_mm2", minRegionMm2},
                {"missed_regions_count", m.missed.size()},
                {"missed_area_in_listed_regions_mm2", m.missedInListedRegionsMm2},
                {"missed_regions", missedRegionsJson(m.missed)}};
}

/// Per vertex: 1 when every triangle around it was seen, so a missed region shows in full
/// (its border vertices are 0) and a miss is never hidden by interpolation in a viewer.
std::vector<uint8_t> vertexSeen(const RayScene& scene, const std::vector<uint8_t>& triangleSeen)
{
    std::vector<uint8_t> v(scene.vertexCount(), 1);
    for (uint32_t f = 0; f < scene.triangleCount(); ++f) {
        if (triangleSeen[f]) continue;
        for (const uint32_t i : scene.triangle(f)) v[i] = 0;
    }
    return v;
}

/// surface_seen.ply: binary PLY with per-vertex seen_flyover, seen_flythrough (two-way),
/// seen_flythrough_forward (0/1) and a colour: blue where the fly-over missed, orange where
/// only the fly-through missed, tissue elsewhere.
void writeSurfaceSeen(const std::string& path, const RayScene& scene, const CoverageResult& cov)
{
    const auto flyover = vertexSeen(scene, cov.flyover.seen);
    const auto twoWay = vertexSeen(scene, cov.flythroughTwoWay.seen);
    const auto forward = vertexSeen(scene, cov.flythroughForward.seen);
    TrianglePly ply;
    ply.vertices = scene.vertexCount();
    ply.faces = scene.triangleCount();
    ply.comments = {"flyover surface_seen: 1 = every triangle around the vertex was hit by a primary ray",
                    "colour: blue = missed by the fly-over, orange = missed by the two-way fly-through only"};
    ply.vertexUchars = {"red", "green", "blue", "seen_flyover", "seen_flythrough", "seen_flythrough_forward"};
    ply.vertex = [&](std::size_t i, float* xyz, uint8_t* props) {
        const Vec3d p = scene.vertex(uint32_t(i));
        xyz[0] = float(p.x), xyz[1] = float(p.y), xyz[2] = float(p.z);
        uint8_t rgb[3] = {225, 170, 160};
        if (!flyover[i]) rgb[0] = 30, rgb[1] = 80, rgb[2] = 230;
        else if (!twoWay[i]) rgb[0] = 245, rgb[1] = 170, rgb[2] = 30;
        const uint8_t values[6] = {rgb[0], rgb[1], rgb[2], flyover[i], twoWay[i], forward[i]};
        std::memcpy(props, values, sizeof values);
    };
    ply.face = [&](std::size_t f, int32_t* idx) {
        int k = 0;
        for (const uint32_t v : scene.triangle(uint32_t(f))) idx[k++] = int32_t(v);
        return true;
    };
    writeAtomically(path, [&](const std::string& tmp) { writeTrianglePly(tmp, ply); });
}

/// Review views after the fly-over's coverage (render.review): plans them (render/review.h),
/// renders each into `folder` as review_NNNN.png (a pair like frames/, or one targeted view)
/// with poses.json, and returns what coverage.json says about them: "flyover_with_review",
/// "review_views" and "review". With render.review off the folder holds an empty poses.json.
json renderReview(const RayScene& scene, const Centerline& cl, const CoverageParams& cp,
                  const std::vector<double>& frameRadii, const CoverageResult& cov, const RenderParams& rp,
                  const RenderOptions& ro, const RenderInputs& in, StagedFolder& folder, Progress* progress,
                  std::vector<uint8_t>& withReviewSeen)
{
    withReviewSeen = cov.flyover.seen;
    const double clStep = cl.stepMm > 0 ? cl.stepMm : 1.0;
    json poses = json::array();
    json out{{"flyover_with_review", nullptr}, {"review_views", 0}};
    if (!rp.review) {
        writeJson(folder.path("poses.json"), json{{"schema", "flyover.review_poses/1"},
                                                  {"world_frame", WORLD_FRAME},
                                                  {"enabled", false},
                                                  {"views", poses}});
        out["review"] = json{{"enabled", false}};
        return out;
    }
    ReviewParams params;
    params.targetFraction = rp.reviewTarget;
    params.minRegionMm2 = cp.minRegionMm2;
    const ReviewResult review = planReview(scene, cl, cp, frameRadii, cov, params, progress);
    withReviewSeen = review.withReview.seen;

    std::vector<json> views(review.views.size());
    tbb::parallel_for(std::size_t(0), review.views.size(), [&](std::size_t k) {
        const ReviewView& v = review.views[k];
        char name[32];
        std::snprintf(name, sizeof name, "review_%04zu.png", k);
        RgbImage image;
        const RenderOptions vro = loopLocal(ro, in, rp, v.centerlineIndex, clStep);
        if (v.cameras.size() == 2)
            renderPair(scene, v.cameras[0], v.cameras[1], vro, image);
        else
            renderView(scene, v.cameras[0], vro, image);
        writePng(folder.path(name), image);
        json cams = json::array();
        for (const Camera& c : v.cameras) cams.push_back(cameraJson(c));
        views[k] = json{{"view", k},
                        {"file", name},
                        {"kind", v.kind},
                        {"round", v.round},
                        {"centerline_index", v.centerlineIndex},
                        {"arc_mm", double(v.centerlineIndex) * clStep},
                        {"centerline_point_mm", vec3Json(cl.points[v.centerlineIndex].positionMm)},
                        {"roll_deg", v.rollDeg},
                        {"frame_radius_mm", v.frameRadiusMm},
                        {"added_area_mm2", v.addedAreaMm2},
                        {"flyover_region", v.flyoverRegion >= 0 ? json(v.flyoverRegion) : json(nullptr)},
                        {"region_centroid_mm", vec3Json(v.regionCentroidMm)},
                        {"region_area_mm2", v.regionAreaMm2},
                        {"cameras", cams}};
    });
    writeJson(folder.path("poses.json"),
              json{{"schema", "flyover.review_poses/1"},
                   {"world_frame", WORLD_FRAME},
                   {"enabled", true},
                   {"layout", "pair views (kind *_pair): camera 0 left, camera 1 right; targeted views: one image"},
                   {"flyover_region_rule", "index into coverage.json flyover.both_cameras.missed_regions of the "
                                           "region the view adds the most area to (null: only smaller ones)"},
                   {"render", renderOptionsJson(ro)},
                   {"views", views}});

    json missed = missedRegionsJson(review.withReview.missed);
    for (std::size_t r = 0; r < review.unreached.size(); ++r) {
        missed[r]["reason"] = review.unreached[r].reason;
        missed[r]["best_candidate_area_mm2"] = review.unreached[r].bestCandidateAreaMm2;
    }
    json withReview = methodJson(review.withReview, cp.minRegionMm2);
    withReview["missed_regions"] = missed;
    withReview["target"] = params.targetFraction;
    withReview["target_reached"] = review.targetReached;
    out["flyover_with_review"] = withReview;
    out["review_views"] = review.views.size();
    out["review"] = json{{"enabled", true},
                         {"target", params.targetFraction},
                         {"min_region_mm2", params.minRegionMm2},
                         {"views", review.views.size()},
                         {"candidates_evaluated", review.candidatesEvaluated},
                         {"rounds", review.rounds},
                         {"rays", review.rays},
                         {"poses", "review/poses.json"}};
    return out;
}

/// The seen share of each anatomical segment's wall, by the fly-over and with review: a
/// triangle's segment is its owner's (loop-local OST: the path point that sees it through the
/// lumen), or its nearest centerline point's when it has none.
json segmentCoverageJson(const RayScene& scene, const Centerline& cl, const RenderInputs& in,
                         const std::vector<uint8_t>& flyoverSeen, const std::vector<uint8_t>& withReviewSeen)
{
    const TriangleGeometry geo = triangleGeometry(scene, &cl);
    const CenterlineLocator locator(cl);
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    std::vector<std::size_t> index(geo.areaMm2.size());
    for (std::size_t f = 0; f < index.size(); ++f) {
        const float arc = in.ownerArcMm.empty() ? std::numeric_limits<float>::quiet_NaN() : in.ownerArcMm[f];
        index[f] = std::isnan(arc) ? locator.nearest(geo.centroidMm[f])
                                   : std::min(cl.points.size() - 1, std::size_t(std::lround(double(arc) / step)));
    }
    const auto alone = segmentSeenShares(flyoverSeen, geo.areaMm2, index, cl.segment);
    const auto reviewed = segmentSeenShares(withReviewSeen, geo.areaMm2, index, cl.segment);
    json out = json::array();
    for (std::size_t k = 0; k < alone.size(); ++k)
        out.push_back(json{{"segment", alone[k].segment},
                           {"area_mm2", alone[k].areaMm2},
                           {"flyover", alone[k].fraction},
                           {"flyover_with_review", k < reviewed.size() ? reviewed[k].fraction : alone[k].fraction}});
    return out;
}

} // namespace

json runCoverage(StudyRun& run, Progress* progress)
{
    const RenderParams& rp = run.opt.params.render;
    StagedFolder coverage(run.dir, "coverage");
    StagedFolder review(run.dir, "review");
    json summary = nullptr, reviewInfo = nullptr;
    double reviewSeconds = 0;
    if (rp.coverage) {
        const RenderInputs& in = run.renderInputs();
        const RayScene& scene = *in.scene;
        reportProgress(progress, 0.05, "coverage rays");
        CoverageParams cp;
        cp.viewPx = rp.coveragePx;
        cp.stepMm = rp.coverageStepMm;
        cp.flyover = flyoverParamsOf(rp);
        cp.ost = rp.ost;
        cp.flythroughFovDeg = rp.flythroughFovDeg;
        cp.frameRadiiMm = in.frameRadii;  // the cameras of the frames and the video
        if (!in.ownerArcMm.empty()) {
            cp.ownerArcMm = &in.ownerArcMm;
            cp.loopReachMm = rp.loopReachMm;
        }
        const CoverageResult cov = computeCoverage(scene, *in.centerline, cp);
        const FlyoverParams& fp = cp.flyover;
        const auto tReview = Clock::now();
        std::vector<uint8_t> withReviewSeen;
        reviewInfo = renderReview(scene, *in.centerline, cp, in.frameRadii, cov, rp, frameOptionsOf(rp), in, review,
                                  progress, withReviewSeen);
        reviewSeconds = secondsSince(tReview);
        json coverageJson{{"schema", "flyover.coverage/1"},
                       {"world_frame", WORLD_FRAME},
                       {"total_area_mm2", cov.totalAreaMm2},
                       {"triangles", scene.triangleCount()},
                       {"sampling",
                        {{"rule", "a triangle is seen when at least one primary ray of the method hits it; "
                                  "fraction = area of seen triangles / total area"},
                         {"view_px", cp.viewPx},
                         {"step_mm", cp.stepMm},
                         {"positions", cov.positions},
                         {"rays", cov.rays}}},
                       {"flyover",
                        {{"fov_deg", fp.fovDeg},
                         {"roll_deg", fp.rollDeg},
                         {"clip_offset_fraction", fp.clipOffsetFraction},
                         {"clip_offset_mm", fp.clipOffsetMm},
                         {"ost", cp.ost},
                         {"loop_local", loopJson(in, rp)},
                         {"both_cameras", methodJson(cov.flyover, cp.minRegionMm2)}}},
                       {"flythrough",
                        {{"fov_deg", cp.flythroughFovDeg},
                         {"one_way_forward", methodJson(cov.flythroughForward, cp.minRegionMm2)},
                         {"one_way_backward", methodJson(cov.flythroughBackward, cp.minRegionMm2)},
                         {"two_way", methodJson(cov.flythroughTwoWay, cp.minRegionMm2)}}},
                       {"vertex_rule", "surface_seen.ply: a vertex is 1 when every triangle around it was seen"}};
        if (cov.leftOutAreaMm2 > 0)  // only then: other studies' coverage.json stay byte for byte
            coverageJson["left_out"] = json{{"area_mm2", cov.leftOutAreaMm2},
                                            {"reason", "the wall round the narrow tube at the lumen's far end that "
                                                       "the path leaves out (centerline.json left_out_branch: the "
                                                       "terminal ileum off the cecum); not in total_area_mm2 nor in "
                                                       "any fraction"}};
        for (auto it = reviewInfo.begin(); it != reviewInfo.end(); ++it) coverageJson[it.key()] = it.value();
        if (!in.centerline->segment.empty())
            coverageJson["segments"] = segmentCoverageJson(scene, *in.centerline, in, cov.flyover.seen, withReviewSeen);
        writeJson(coverage.path("coverage.json"), coverageJson);
        writeSurfaceSeen(coverage.path("surface_seen.ply"), scene, cov);
        summary = json{{"flyover", cov.flyover.fraction},
                       {"flythrough_one_way_forward", cov.flythroughForward.fraction},
                       {"flythrough_one_way_backward", cov.flythroughBackward.fraction},
                       {"flythrough_two_way", cov.flythroughTwoWay.fraction},
                       {"flyover_missed_regions", cov.flyover.missed.size()}};
        if (rp.review) {
            summary["flyover_with_review"] = reviewInfo["flyover_with_review"]["fraction"];
            summary["review_views"] = reviewInfo["review_views"];
        }
    } else {
        writeJson(review.path("poses.json"), json{{"schema", "flyover.review_poses/1"},
                                                  {"world_frame", WORLD_FRAME},
                                                  {"enabled", false},
                                                  {"views", json::array()}});
    }
    reportProgress(progress, 1.0, "coverage done");
    coverage.commit();
    review.commit();
    return json{{"coverage", summary}, {"review_seconds", reviewSeconds}};
}

} // namespace flyover
