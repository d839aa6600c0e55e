#include "colon/params.h"

#include "pipeline/param_json.h"

#include "volume/error.h"

#include <cmath>
#include <optional>
#include <sstream>

namespace flyover {

namespace {

using nlohmann::json;

// One visit function per stage lists its parameters once; JSON output, strict JSON input
// and the --help listing are all derived from it.
template <typename V> void visit(IngestParams& p, V&& v)
{
    v("voxel_mm", p.voxelMm, "isotropic voxel size in mm (0 = smallest input spacing)");
    v("outside_air_hu", p.outsideAirHu, "air outside the body is below this (HU)");
    v("background_hu", p.backgroundHu, "value of the inactive background (HU)");
    v("dicom_series", p.dicomSeries, "DICOM folder: Series Instance UID to read (\"\" = the series with the most slices)");
    v("allow_gaps", p.allowGaps, "DICOM: accept missing slices or uneven slice steps (warned; sampled at true positions)");
}
template <typename V> void visit(SegmentParams& p, V&& v)
{
    v("air_threshold_hu", p.airThresholdHu, "air candidates are below this (HU)");
    v("surface_iso_hu", p.surfaceIsoHu, "lumen surface against air: partial-volume midpoint of air and wall (HU)");
    v("min_component_ml", p.minComponentMl, "drop air components smaller than this (mL)");
    v("lung_min_mean_hu", p.lungMinMeanHu, "a component with mean HU above this is lung (HU)");
    v("keep_fraction", p.keepFraction, "keep components >= this fraction of the largest (or of the seeded one)");
    v("band_voxels", p.bandVoxels, "exterior narrow band of the level set (voxels)");
    v("seed_mm", p.seedMm, "colon component: the one containing [x,y,z] LPS mm (or within 10 mm), or null = the largest");
    v("cleanse", p.cleanse, "join tagged fluid under air-fluid levels to the lumen (electronic cleansing)");
    v("fluid_threshold_hu", p.fluidThresholdHu, "tagged fluid is above this (HU)");
    v("wall_hu", p.wallHu, "colon wall (HU): the surface in fluid lies midway between it and the fluid");
    v("mask_label", p.maskLabel, "--mask: the label that is lumen (0 = every non-zero voxel)");
    v("mask_smoothing_voxels", p.maskSmoothingVoxels, "--mask: constrained smoothing of the mask's staircase (mask voxels, 0 = none)");
    v("cut_contacts", p.contacts.enabled, "find contacts between touching loops (a narrow link closing a cycle) and cut them");
    v("contact_neck_ratio", p.contacts.maxNeckRatio, "a contact's neck radius / the lumen radius either side is below this (0..1]");
}
template <typename V> void visit(CenterlineParams& p, V&& v)
{
    v("step_mm", p.stepMm, "arc-length step of the centerline (mm)");
    v("wall_penalty", p.wallPenalty, "exponent p of the path cost 1/D^p");
    v("smoothing_mm", p.smoothingMm, "Gaussian smoothing sigma along the path (mm)");
    v("rectum_mm", p.rectumMm, "rectum endpoint override [x,y,z] in LPS mm, or null");
}
template <typename V> void visit(MeshParams& p, V&& v)
{
    v("iso_value_mm", p.isoValueMm, "iso-value of the level set to mesh (mm)");
    v("adaptivity", p.adaptivity, "volumeToMesh adaptivity 0..1 (0 = uniform)");
    v("smooth_method", p.smoothMethod, "taubin (non-shrinking lambda|mu mesh filter) or none");
    v("smooth_iterations", p.smoothIterations, "Taubin lambda|mu iterations (0 = no smoothing)");
    v("smooth_pass_band", p.smoothPassBand, "Taubin pass band k_PB in (0, 1); lower = smoother");
    v("decimate_target_faces", p.decimateTargetFaces, "decimate to this many triangles (0 = no budget)");
    v("decimate_fraction", p.decimateFraction, "decimate to this fraction of the triangles (1 = off)");
    v("decimate_max_error_voxels", p.decimateMaxErrorVoxels,
      "decimation bound: distance of any extracted vertex to the result (voxels; 0 = none)");
    v("decimate_max_normal_deviation_deg", p.decimateMaxNormalDeviationDeg,
      "decimation normal-flip guard: largest normal change per collapse (degrees)");
}
template <typename V> void visit(RenderParams& p, V&& v)
{
    v("width_px", p.widthPx, "width of each fly-over view (pixels)");
    v("height_px", p.heightPx, "height of each fly-over view (pixels)");
    v("fov_deg", p.fovDeg, "field of view of the fly-over cameras (degrees)");
    v("roll_deg", p.rollDeg, "roll of both cameras about the centerline (degrees)");
    v("direction", p.direction, "travel direction on screen: right or left");
    v("clip_offset_fraction", p.clipOffsetFraction, "near plane at d - fraction * D(p)");
    v("clip_offset_mm", p.clipOffsetMm, "near plane at d - offset mm (>= 0 overrides fraction)");
    v("loop_reach_mm", p.loopReachMm, "fly-over and review views pass through walls of the path farther than this along the colon (mm; 0 = every wall)");
    v("frame_step_mm", p.frameStepMm, "distance between saved frame pairs (mm)");
    v("supersample", p.supersample, "n x n rays per pixel");
    v("ost", p.ost, "one-sided transparency (false: plain rendering)");
    v("smooth_shading", p.smoothShading, "shade with interpolated vertex normals (false: flat faces)");
    v("depth_cue", p.depthCue, "darken with depth beyond the near plane");
    v("depth_cue_mm", p.depthCueMm, "depth at which the depth cue halves the brightness (mm)");
    v("overview_px", p.overviewPx, "overview image size (pixels)");
    v("overview_marker_mm", p.overviewMarkerMm, "overview marker at this arc length from the rectum (mm), < 0: none");
    v("flythrough_frames", p.flythroughFrames, "also save fly-through pairs (forward | backward)");
    v("flythrough_fov_deg", p.flythroughFovDeg, "field of view of the fly-through cameras (degrees)");
    v("video", p.video, "MP4 of the whole fly-over in video/ (needs the ffmpeg program)");
    v("video_step_mm", p.videoStepMm, "distance between video frames along the centerline (mm)");
    v("video_fps", p.videoFps, "video frame rate (frames per second)");
    v("coverage", p.coverage, "coverage of fly-over and fly-through, missed regions (coverage/)");
    v("coverage_px", p.coveragePx, "coverage rays per view: coverage_px x coverage_px");
    v("coverage_step_mm", p.coverageStepMm, "distance between coverage views along the centerline (mm)");
    v("review", p.review, "review views for the fly-over's missed regions >= 10 mm^2 (review/; needs coverage)");
    v("review_target", p.reviewTarget, "review until fly-over plus review sees this fraction of the wall (0..1]");
}

template <typename V> void visit(PolypParams& p, V&& v)
{
    v("enabled", p.enabled, "look for polyp candidates (false: polyps/candidates.json lists none)");
    v("shape_index_seed", p.shapeIndexSeed, "a candidate starts where the wall is this cap-like (shape index 0..1, 1 = cap)");
    v("shape_index_grow", p.shapeIndexGrow, "and grows over the wall this cap-like or more");
    v("curvedness_min_per_mm", p.curvednessMinPerMm, "its start bends at least this much (1/mm)");
    v("curvedness_max_per_mm", p.curvednessMaxPerMm, "and at most this much (1/mm; sharper is noise)");
    v("min_size_mm", p.minSizeMm, "candidates are at least this wide (mm)");
    v("min_height_mm", p.minHeightMm, "and rise at least this far above the surrounding wall (mm)");
    v("max_elongation", p.maxElongation, "longest / shortest extent along the wall at most this (folds are longer)");
    v("min_cap_fraction", p.minCapFraction, "the cap covers at least this share of the footprint's disc (0..1)");
    v("max_candidates", p.maxCandidates, "keep the best this many by score");
    v("images", p.images, "an OST pair and, with a CT, axial, coronal and sagittal crops per candidate");
    v("crop_mm", p.cropMm, "side of the CT crops (mm)");
}

template <typename F> void visitStage(PipelineParams& p, const std::string& stage, F&& f)
{
    if (stage == "ingest") return f(p.ingest);
    if (stage == "segment") return f(p.segment);
    if (stage == "centerline") return f(p.centerline);
    if (stage == "mesh") return f(p.mesh);
    if (stage == "render") return f(p.render);
    if (stage == "polyps") return f(p.polyps);
    std::string known;
    for (const auto& s : stageNames()) known += (known.empty() ? "" : ", ") + s;
    throw ParameterError("unknown stage '" + stage + "' (stages: " + known + ")");
}

json toJsonValue(double v) { return v; }
json toJsonValue(int v) { return v; }
json toJsonValue(bool v) { return v; }
json toJsonValue(const std::string& v) { return v; }
json toJsonValue(const std::optional<Vec3d>& v)
{
    return v ? json::array({v->x, v->y, v->z}) : json(nullptr);
}

void fromJsonValue(const json& j, double& out, const std::string& name) { param_json::readNumber(j, out, name); }
void fromJsonValue(const json& j, int& out, const std::string& name) { param_json::readInteger(j, out, name); }
void fromJsonValue(const json& j, bool& out, const std::string& name) { param_json::readBool(j, out, name); }
void fromJsonValue(const json& j, std::string& out, const std::string& name)
{
    if (!j.is_string()) throw ParameterError(name + ": expected a string, got " + j.dump());
    out = j.get<std::string>();
}
void fromJsonValue(const json& j, std::optional<Vec3d>& out, const std::string& name)
{
    if (j.is_null()) { out.reset(); return; }
    if (j.is_string()) {  // "x,y,z" from the command line
        Vec3d v;
        char c1 = 0, c2 = 0;
        std::istringstream in(j.get<std::string>());
        if (in >> v.x >> c1 >> v.y >> c2 >> v.z && c1 == ',' && c2 == ',' && (in >> std::ws).eof()) {
            out = v;
            return;
        }
    } else if (j.is_array() && j.size() == 3 && j[0].is_number() && j[1].is_number() &&
               j[2].is_number()) {
        out = Vec3d{j[0].get<double>(), j[1].get<double>(), j[2].get<double>()};
        return;
    }
    throw ParameterError(name + ": expected [x,y,z] or \"x,y,z\" in mm, got " + j.dump());
}

template <typename P> json paramsToJson(P& p)
{
    json j = json::object();
    visit(p, [&](const char* key, auto& value, const char*) { j[key] = toJsonValue(value); });
    return j;
}

template <typename P> void paramsFromJson(P& p, const json& j, const std::string& stage)
{
    param_json::readObject(
        p, j, stage, stage, [](auto& q, auto&& f) { visit(q, f); },
        [](const json& v, auto& out, const std::string& name) { fromJsonValue(v, out, name); });
}

} // namespace

const std::vector<std::string>& stageNames()
{
    static const std::vector<std::string> names{"ingest", "segment", "centerline", "mesh", "polyps", "render"};
    return names;
}

nlohmann::json stageParamsToJson(const PipelineParams& params, const std::string& stage)
{
    PipelineParams copy = params;
    json j;
    visitStage(copy, stage, [&](auto& p) { j = paramsToJson(p); });
    return j;
}

int stageVersion(const std::string& stage)
{
    if (stage == "ingest") return IngestParams::VERSION;
    if (stage == "segment") return SegmentParams::VERSION * 100 + ContactParams::VERSION;  // contacts: end of segment
    if (stage == "centerline") return CenterlineParams::VERSION;
    if (stage == "mesh") return MeshParams::VERSION;
    if (stage == "render") return RenderParams::VERSION;
    if (stage == "polyps") return PolypParams::VERSION;
    throw ParameterError("unknown stage '" + stage + "'");
}

void applyParamsJson(PipelineParams& params, const nlohmann::json& config, const std::string& source)
{
    if (!config.is_object())
        throw ParameterError(source + ": expected a JSON object of stages");
    for (auto it = config.begin(); it != config.end(); ++it) {
        try {
            visitStage(params, it.key(), [&](auto& p) { paramsFromJson(p, it.value(), it.key()); });
        } catch (const ParameterError& e) {
            throw ParameterError(source + ": " + e.what());
        }
    }
}

void applyParamAssignment(PipelineParams& params, const std::string& assignment)
{
    const auto eq = assignment.find('=');
    const auto dot = assignment.find('.');
    if (eq == std::string::npos || dot == std::string::npos || dot > eq)
        throw ParameterError("--set '" + assignment + "': expected stage.parameter=value");
    const std::string stage = assignment.substr(0, dot);
    const std::string name = assignment.substr(dot + 1, eq - dot - 1);
    const std::string text = assignment.substr(eq + 1);
    json value = json::parse(text, nullptr, /*allow_exceptions=*/false);
    if (value.is_discarded()) value = text;  // a bare word: take it as a string
    applyParamsJson(params, json{{stage, json{{name, value}}}}, "--set " + stage + "." + name);
}

void validateParams(const PipelineParams& p)
{
    auto require = [](bool ok, const std::string& name, const std::string& what) {
        if (!ok) throw ParameterError(name + ": " + what);
    };
    require(p.ingest.voxelMm >= 0, "ingest.voxel_mm", "must be >= 0 (0 = smallest input spacing)");
    require(p.segment.airThresholdHu < p.segment.surfaceIsoHu, "segment.air_threshold_hu",
            "must be below segment.surface_iso_hu");
    require(p.segment.minComponentMl >= 0, "segment.min_component_ml", "must be >= 0");
    require(p.segment.keepFraction >= 0 && p.segment.keepFraction <= 1, "segment.keep_fraction",
            "must be in [0, 1]");
    require(p.segment.bandVoxels >= 1 && p.segment.bandVoxels <= 10, "segment.band_voxels",
            "must be in [1, 10]");
    require(p.segment.fluidThresholdHu > p.segment.wallHu, "segment.fluid_threshold_hu",
            "must be above segment.wall_hu");
    require(p.segment.maskLabel >= 0, "segment.mask_label", "must be >= 0 (0 = every non-zero voxel)");
    require(p.segment.maskSmoothingVoxels >= 0 && p.segment.maskSmoothingVoxels <= 8,
            "segment.mask_smoothing_voxels", "must be in [0, 8]");
    require(p.segment.contacts.maxNeckRatio > 0 && p.segment.contacts.maxNeckRatio <= 1,
            "segment.contact_neck_ratio", "must be in (0, 1]");
    require(p.centerline.stepMm > 0, "centerline.step_mm", "must be > 0");
    require(p.centerline.wallPenalty >= 0, "centerline.wall_penalty", "must be >= 0");
    require(p.centerline.smoothingMm >= 0, "centerline.smoothing_mm", "must be >= 0");
    require(p.mesh.adaptivity >= 0 && p.mesh.adaptivity <= 1, "mesh.adaptivity", "must be in [0, 1]");
    require(p.mesh.smoothMethod == "taubin" || p.mesh.smoothMethod == "none", "mesh.smooth_method",
            "must be taubin or none");
    require(p.mesh.smoothIterations >= 0, "mesh.smooth_iterations", "must be >= 0");
    require(p.mesh.smoothPassBand > 0 && p.mesh.smoothPassBand < 1, "mesh.smooth_pass_band", "must be in (0, 1)");
    require(p.mesh.decimateTargetFaces >= 0, "mesh.decimate_target_faces", "must be >= 0");
    require(p.mesh.decimateFraction > 0 && p.mesh.decimateFraction <= 1, "mesh.decimate_fraction",
            "must be in (0, 1]");
    require(p.mesh.decimateMaxErrorVoxels >= 0, "mesh.decimate_max_error_voxels", "must be >= 0");
    require(p.mesh.decimateMaxNormalDeviationDeg > 0 && p.mesh.decimateMaxNormalDeviationDeg <= 180,
            "mesh.decimate_max_normal_deviation_deg", "must be in (0, 180]");
    require(p.render.widthPx >= 8 && p.render.widthPx <= 8192, "render.width_px", "must be in [8, 8192]");
    require(p.render.heightPx >= 8 && p.render.heightPx <= 8192, "render.height_px", "must be in [8, 8192]");
    require(p.render.fovDeg >= 10 && p.render.fovDeg <= 170, "render.fov_deg", "must be in [10, 170]");
    require(p.render.direction == "right" || p.render.direction == "left", "render.direction",
            "must be right or left");
    require(p.render.clipOffsetFraction >= 0, "render.clip_offset_fraction", "must be >= 0");
    require(p.render.frameStepMm > 0, "render.frame_step_mm", "must be > 0");
    require(p.render.supersample >= 1 && p.render.supersample <= 8, "render.supersample", "must be in [1, 8]");
    require(p.render.overviewPx >= 16 && p.render.overviewPx <= 8192, "render.overview_px",
            "must be in [16, 8192]");
    require(p.render.clipOffsetMm >= 0 || p.render.clipOffsetMm == -1.0, "render.clip_offset_mm",
            "must be >= 0, or -1 to use render.clip_offset_fraction");
    require(p.render.depthCueMm > 0, "render.depth_cue_mm", "must be > 0");
    require(p.render.flythroughFovDeg >= 10 && p.render.flythroughFovDeg <= 170, "render.flythrough_fov_deg",
            "must be in [10, 170]");
    require(p.render.videoStepMm > 0, "render.video_step_mm", "must be > 0");
    require(p.render.videoFps >= 1 && p.render.videoFps <= 120, "render.video_fps", "must be in [1, 120]");
    require(p.render.coveragePx >= 8 && p.render.coveragePx <= 4096, "render.coverage_px", "must be in [8, 4096]");
    require(p.render.coverageStepMm > 0, "render.coverage_step_mm", "must be > 0");
    require(p.render.loopReachMm >= 0 && p.render.loopReachMm <= 1e6, "render.loop_reach_mm", "must be in 0..1e6 mm");
    validatePolypParams(p.polyps);
    require(p.render.reviewTarget > 0 && p.render.reviewTarget <= 1, "render.review_target", "must be in (0, 1]");
}

std::string describeParams()
{
    PipelineParams p;
    std::ostringstream os;
    for (const auto& stage : stageNames()) {
        visitStage(p, stage, [&](auto& sp) {
            visit(sp, [&](const char* key, auto& value, const char* help) {
                os << "  " << stage << "." << key << " = " << toJsonValue(value).dump() << "\n      "
                   << help << "\n";
            });
        });
    }
    return os.str();
}

} // namespace flyover
