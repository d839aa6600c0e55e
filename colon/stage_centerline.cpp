#include "colon/study_run.h"

#include "pipeline/artifact_io.h"
#include "colon/uncut_lumen.h"
#include "colon/anatomy_segments.h"
#include "volume/scan_orientation.h"
#include "colon/centerline.h"
#include "colon/segment.h"

#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <vector>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

json runCenterline(StudyRun& run, Progress* progress)
{
    auto sdf = run.sdf();
    // The early node's centerline of this very lumen, traced beside the segment stage's contact
    // cut, when it traced one and the cut removed nothing; else traced here. The rectal tube's
    // tip (found by segment) is the rectum hint unless --rectum-mm gave one.
    const std::shared_ptr<UncutLumen> uncut = run.state.uncutLumen;
    const bool besideCut = uncut && uncut->isFinal() && uncut->centerline.has_value();
    bool fromTube = false;
    const CenterlineParams params = centerlineParamsFor(*sdf, run.opt.params.centerline, fromTube);
    CenterlineReport cr;
    Centerline c;
    if (besideCut) {
        c = std::move(*uncut->centerline);
        uncut->centerline.reset();
        cr = uncut->centerlineReport;
        fromTube = uncut->centerlineFromTube;
    } else {
        c = extractCenterline(*sdf, params, progress, &cr);
    }
    // Segment names and landmarks from the path's geometry in the patient frame the scan's
    // header states (the CT's, else the mask's); from the path alone where it states none, or
    // where the path contradicts it (anatomy_segments.h).
    const std::string& scan = run.opt.ctPath.empty() ? run.opt.maskPath : run.opt.ctPath;
    addAnatomySegments(c, scan.empty() || scanStatesOrientation(scan) ? PatientFrame::Stated : PatientFrame::Unknown);
    if (run.opt.log && c.segmentsFrame != "patient")
        run.opt.log->message("centerline: segments labelled from the path alone: " + c.segmentsFrameReason);
    writeJson(run.path("centerline.json"), centerlineToJson(c));
    run.state.centerline = std::move(c);
    const Centerline& cl = *run.state.centerline;
    const auto& pts = cl.points;

    // What the path squeezes through, and what was cut on its way (segment stage).
    json nearWall = json::array();
    for (const CenterlineNearWall& w : cr.nearWall) {
        nearWall.push_back(json{{"from_arc_mm", w.fromArcMm},
                                {"to_arc_mm", w.toArcMm},
                                {"min_radius_mm", w.minRadiusMm},
                                {"position_mm", vec3Json(w.positionMm)}});
        if (run.opt.log) {
            std::ostringstream msg;
            msg << std::fixed << std::setprecision(1) << "centerline: warning: the path passes "
                << w.minRadiusMm << " mm from the wall (under " << run.opt.params.centerline.nearWallMm
                << " mm, not a bridged gap) at arc " << w.fromArcMm << "-" << w.toArcMm << " mm, ("
                << w.positionMm.x << ", " << w.positionMm.y << ", " << w.positionMm.z << ") mm";
            run.opt.log->message(msg.str());
        }
    }
    json bridges = json::array();
    for (const CenterlineBridgeInfo& b : cr.bridges)
        bridges.push_back(json{{"gap_mm", b.gapMm}, {"length_mm", b.lengthMm}});
    // The pieces the path runs through, in travel order, and where each one's route was found.
    std::vector<const CenterlinePieceInfo*> travelled;
    for (const CenterlinePieceInfo& p : cr.pieces)
        if (p.used) travelled.push_back(&p);
    std::sort(travelled.begin(), travelled.end(),
              [](const CenterlinePieceInfo* a, const CenterlinePieceInfo* b) { return a->chainIndex < b->chainIndex; });
    json pieces = json::array();
    for (const CenterlinePieceInfo* p : travelled)
        pieces.push_back(json{{"volume_ml", p->volumeMl},
                              {"path_length_mm", p->pathLengthMm},
                              {"route_searched_on", p->routeSearchedOn}});
    const double aboveLowest = pts.empty() ? 0.0 : pts.front().positionMm.z - cr.lowestLumenMm.z;
    // The rectum end far above the lowest lumen point without a hint: the path may have missed
    // the rectum; the study is flagged for review (`flyover status`), never a silent success.
    json needsReview = json::array();
    if (!run.opt.params.centerline.rectumMm && aboveLowest > LOWEST_END_SLACK_MM) {
        std::ostringstream why;
        why << std::fixed << std::setprecision(0) << "the path starts " << aboveLowest
            << " mm above the lowest lumen point (" << cr.lowestLumenMm.x << ", " << cr.lowestLumenMm.y << ", "
            << cr.lowestLumenMm.z << ") LPS mm, more than " << LOWEST_END_SLACK_MM
            << " mm: the rectum may be missed; give --rectum-mm";
        needsReview.push_back(why.str());
        if (run.opt.log) run.opt.log->message("centerline: warning: " + why.str());
    }
    if (cr.turnsOver30 > 0) {
        std::ostringstream why;
        why << std::fixed << std::setprecision(0) << "the path turns more than 30 degrees in " << cr.turnsOver30
            << " steps (largest " << cr.maxTurnDeg << "): the fly-over cameras may spin there";
        needsReview.push_back(why.str());
        if (run.opt.log) run.opt.log->message("centerline: warning: " + why.str());
    }
    json leftOut = json::array();
    for (const LeftOutLumen& r : cr.leftOut) {
        leftOut.push_back(json{{"volume_ml", r.volumeMl},
                               {"centroid_mm", vec3Json(r.centroidMm)},
                               {"arc_mm", r.arcMm < 0 ? json() : json(r.arcMm)},
                               {"extent_mm", r.extentMm},
                               {"kind", r.kind},
                               {"reason", r.reason}});
        const bool expected = r.kind == "dead end" || r.kind == "far branch";
        if (run.opt.log) run.opt.log->message("centerline: " + std::string(expected ? "" : "warning: ") +
                                              "left out: " + r.reason);
        if (r.kind == "not entered") needsReview.push_back("lumen left out: " + r.reason);
    }
    json farBranch;  // null: none left out
    if (const auto& f = cr.farBranchLeftOut) {
        farBranch = json{{"handling", "a narrow tube off the wide lumen at the far end (the terminal ileum, gas-filled "
                                      "through an open ileocecal valve, or the appendix, off the cecum) is left out: the path ends at "
                                      "the wide lumen's own end"},
                         {"mouth_mm", vec3Json(f->mouthMm)},
                         {"tube_end_mm", vec3Json(f->endMm)},
                         {"tube_length_mm", f->lengthMm},
                         {"tube_radius_mm", f->depthMm},
                         {"wide_radius_mm", f->wideDepthMm},
                         {"wide_end_beyond_mouth_mm", f->wideEndBeyondMouthMm}};
        if (run.opt.log) {
            std::ostringstream line;
            line << std::fixed << std::setprecision(0) << "centerline: a narrow tube (radius " << f->depthMm
                 << " mm, " << f->lengthMm << " mm followed) leaves the wide lumen (radius " << f->wideDepthMm
                 << " mm) near its far end at (" << f->mouthMm.x << ", " << f->mouthMm.y << ", " << f->mouthMm.z
                 << ") LPS mm, as the terminal ileum or the appendix leaves the cecum; left out: the path ends at the wide lumen's "
                    "own end, "
                 << f->wideEndBeyondMouthMm << " mm beyond it";
            run.opt.log->message(line.str());
        }
    }
    return json{{"traced_beside_contact_cut", besideCut},
                {"points", pts.size()},
                {"length_mm", cl.lengthMm()},
                {"world_frame", "LPS"},
                {"rectum_mm", pts.empty() ? json() : vec3Json(pts.front().positionMm)},
                {"cecum_mm", pts.empty() ? json() : vec3Json(pts.back().positionMm)},
                {"rectum_hint", fromTube ? "rectal tube tip" : (params.rectumMm ? "rectum_mm" : "none")},
                {"rectum_rule", cr.rectumRule},
                {"segments_frame", cl.segmentsFrame},
                {"rectum_above_lowest_lumen_mm", aboveLowest},
                {"needs_review", needsReview},
                {"turns", {{"max_step_deg", cr.maxTurnDeg},
                           {"steps_over_30_deg", cr.turnsOver30},
                           {"max_normal_step_deg", cr.maxNormalStepDeg},
                           {"normal_steps_over_15_deg", cr.normalStepsOver15}}},
                {"pieces", pieces},
                {"bridges", bridges},
                {"near_wall", nearWall},
                {"far_branch_left_out", farBranch},
                {"left_out_lumen", leftOut},
                {"contacts", contactsAlongPath(*sdf, cl)}};
}

} // namespace flyover
