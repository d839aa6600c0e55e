#include "colon/study_run.h"

#include "pipeline/artifact_io.h"
#include "colon/uncut_lumen.h"
#include "volume/image_io.h"
#include "volume/threads.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"

#include <tbb/task_arena.h>

#include <filesystem>
#include <iomanip>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {


namespace {

json matrixJson(const Mat3d& m)
{
    json rows = json::array();
    for (const auto& r : m) rows.push_back(json::array({r[0], r[1], r[2]}));
    return rows;
}

json geometryJson(const ImageGeometry& g)
{
    return json{{"size", g.size},
                {"spacing_mm", vec3Json(g.spacingMm)},
                {"origin_mm", vec3Json(g.originMm)},
                {"direction", matrixJson(g.direction)}};
}

/// The manifest report of a segmentation (both sources).
json segmentationJson(const LumenSegmentation& seg)
{
    json pieces = json::array();
    for (const auto& p : seg.pieces)
        pieces.push_back(json{{"order", p.order},
                              {"volume_ml", p.volumeMl},
                              {"centroid_mm", vec3Json(p.centroidMm)},
                              {"min_mm", vec3Json(p.minMm)},
                              {"max_mm", vec3Json(p.maxMm)},
                              {"frame_angle_deg", p.frameAngleDeg}});
    json comps = json::array();
    for (const auto& c : seg.components)
        comps.push_back(json{{"volume_ml", c.volumeMl},    {"mean_hu", c.meanHu},
                             {"centroid_mm", vec3Json(c.centroidMm)},
                             {"min_mm", vec3Json(c.minMm)}, {"max_mm", vec3Json(c.maxMm)},
                             {"kept", c.kept},             {"reason", c.reason}});
    json pools = json::array();
    for (const auto& p : seg.fluidPools)
        pools.push_back(json{{"volume_ml", p.volumeMl},     {"mean_hu", p.meanHu},
                             {"surface_hu", p.surfaceHu},   {"level_mm", p.levelMm},
                             {"min_mm", vec3Json(p.minMm)}, {"max_mm", vec3Json(p.maxMm)},
                             {"joined", p.joined},          {"reason", p.reason}});
    const RectalTube& t = seg.rectalTube;
    json tube = json{{"found", t.found}};
    if (t.found) {
        json axis = json::array();
        for (const Vec3d& p : t.axisMm) axis.push_back(vec3Json(p));
        tube = json{{"found", true},
                    {"handling", "left out of the lumen, the surface and the path: cut where it leaves the colon, "
                                 "filled (given to the lumen) where the colon's lumen (air or tagged fluid) "
                                 "surrounds it; its tip is the centerline's rectum hint unless rectum_mm is set"},
                    {"tip_mm", vec3Json(t.tipMm)},
                    {"entry_mm", vec3Json(t.entryMm)},
                    {"outer_end_mm", vec3Json(t.outerEndMm)},
                    {"length_mm", t.lengthMm},
                    {"diameter_mm", t.diameterMm},
                    {"volume_ml", t.volumeMl},
                    {"filled_ml", t.filledMl},
                    {"axis_mm", axis}};
    }
    return json{{"lumen_volume_ml", seg.lumenVolumeMl},
                {"rectal_tube", tube},
                {"mask_volume_ml", seg.maskVolumeMl},
                {"fluid_volume_ml", seg.fluidVolumeMl},
                {"gravity_direction", vec3Json(seg.gravityDirection)},
                {"pieces_order", "frame angle: around the lumen's centroid in the coronal plane, from "
                                 "inferior-right through the patient's left, superior and right "
                                 "(rectum -> cecum for a normal colon)"},
                {"pieces", pieces},
                {"components", comps},
                {"fluid_pools", pools}};
}

/// One line in the run log when the lumen is in several pieces (a collapsed colon).
void reportPieces(const StudyRun& run, const LumenSegmentation& seg)
{
    if (!run.opt.log || seg.pieces.size() < 2) return;
    run.opt.log->message("segment: " + describeLumenPieces(seg.pieces, run.opt.params.centerline));
}

json writeSegmentation(StudyRun& run, LumenSegmentation& seg)
{
    // The lumen before the cut, for the mesh and the centerline made beside it (uncut_lumen.h;
    // not with --threads 1: they would wait for the cut anyway).
    std::shared_ptr<UncutLumen> uncut;
    const int readers = run.earlyReaders("segment:uncut-lumen");
    if (readers > 0 && threadsThatMayRun() > 1 && seg.sdf && UncutLumen::applicable(*seg.sdf))
        uncut = std::make_shared<UncutLumen>(seg.sdf->deepCopy(), readers);
    run.state.uncutLumen = uncut;
    run.handOn("segment:uncut-lumen");
    // Isolated: while waiting inside the cut's parallel loops this thread takes none of the
    // early nodes' work, which would hold the cut's end back.
    json contacts = tbb::this_task_arena::isolate([&] { return cutLumenContacts(run, seg); });  // stage_contacts.cpp
    // A cut: the early nodes stop, the mesh and centerline stages work on the cut lumen.
    if (uncut && contacts.value("cut", -1) != 0) uncut->superseded = true;
    writeGrids(run.path("lumen.vdb"), {seg.mask, seg.sdf});
    run.state.sdf = seg.sdf;
    reportPieces(run, seg);
    json report = segmentationJson(seg);
    report["contacts"] = std::move(contacts);
    return report;
}

} // namespace

json runSegment(StudyRun& run, Progress* progress)
{
    if (!run.state.hu)
        run.state.hu = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(run.path("ct.vdb"), "ct_hu"));
    // Made beside the ingest stage's writing of ct.vdb when ingest ran in this run.
    const std::shared_ptr<LumenSegmentation> early = std::move(run.state.earlySegmentation);
    const bool besideCtWrite = bool(early);
    LumenSegmentation seg = early ? std::move(*early) : segmentLumen(*run.state.hu, run.opt.params.segment, progress);
    // No later stage reads the HU grid: its 200+ MB go before the contact cut, the mesh and the
    // centerline allocate theirs (ct.vdb is already written; a later run reads it from there).
    run.state.hu.reset();
    json report = writeSegmentation(run, seg);
    report["source"] = "ct";
    report["segmented_beside_ct_write"] = besideCtWrite;
    return report;
}

json runSegmentFromMask(StudyRun& run, const std::string& maskPath, Progress* progress)
{
    if (!run.opt.ctPath.empty() && !run.state.hu)
        run.state.hu = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(run.path("ct.vdb"), "ct_hu"));
    const SegmentParams& params = run.opt.params.segment;
    MaskSummary summary;
    LumenSegmentation seg;
    {
        auto source = openImage(maskPath);
        seg = segmentFromMask(*source, params, run.state.hu.get(), progress, &summary);
        checkPlausibleColon(seg, params, maskPath);
    }
    run.state.hu.reset();  // as in runSegment: no later stage reads it
    if (run.opt.log && summary.voxelsOutsideReference > 0)
        run.opt.log->message("segment: warning: " + std::to_string(summary.voxelsOutsideReference) +
                             " mask voxels lie outside the CT's extent");
    json report = writeSegmentation(run, seg);
    report["source"] = "mask";
    report["mask"] = json{{"path", fs::absolute(maskPath).string()},
                          {"label", params.maskLabel},
                          {"label_voxels", summary.labelVoxels},
                          {"labels_present", summary.labelsPresent},
                          {"resampled", summary.resampled},
                          {"voxels_outside_ct", summary.voxelsOutsideReference},
                          {"geometry", geometryJson(summary.geometry)}};
    return report;
}

} // namespace flyover
