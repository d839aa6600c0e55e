/// @file params.h
/// @brief Every stage's parameters, their canonical JSON form and strict parsing.
///
/// Parameter names in JSON, in `--set stage.name=value` and in config files are the
/// snake_case names listed by each visit function below. Parsing rejects unknown names
/// (a typo is an error, never silently ignored) and values of the wrong type or range.
#pragma once

#include "render/camera.h"
#include "surface/extract_surface.h"
#include "colon/centerline.h"
#include "volume/ingest.h"
#include "colon/polyp_detect.h"
#include "colon/segment.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// Parameters of the render stage: fly-over frames and video, fly-through frames for
/// comparison, the six overviews, coverage.
struct RenderParams {
    int widthPx = 512;               ///< width of each fly-over view (pixels)
    int heightPx = 512;              ///< height of each fly-over view (pixels)
    double fovDeg = 90.0;            ///< fly-over field of view (degrees, 10..170)
    double rollDeg = 0.0;            ///< rotation of both cameras about the centerline (degrees)
    std::string direction = "right"; ///< travel towards image "right" or "left"
    /// Near plane at d - fraction * D(p) (thesis V.B). 0.5 chosen by measurement: see
    /// bench/render_bench --clip-sweep and the render stage's notes.
    double clipOffsetFraction = 0.5;
    double clipOffsetMm = -1.0;      ///< if >= 0: near plane at d - this many mm instead
    /// Loop-local OST: fly-over and review views pass through walls that belong (through the
    /// lumen, render/loop_ownership.h) to parts of the path more than this far along the colon
    /// from the view's own place (mm); 0: the thesis' OST, every wall shown.
    double loopReachMm = 80.0;
    double frameStepMm = 10.0;       ///< distance between saved frame pairs along the centerline (mm)
    int supersample = 1;             ///< n x n rays per pixel
    bool ost = true;                 ///< one-sided transparency (false: plain rendering)
    bool smoothShading = true;       ///< interpolated vertex normals (false: flat faces)
    bool depthCue = true;            ///< darken with depth beyond the near plane
    double depthCueMm = 60.0;        ///< depth at which the depth cue halves the brightness (mm)
    int overviewPx = 768;            ///< overview image size (pixels, square)
    double overviewMarkerMm = -1.0;  ///< marker at this arc length from the rectum (mm); < 0: none
    bool flythroughFrames = true;    ///< also save fly-through pairs (forward | backward)
    double flythroughFovDeg = 90.0;  ///< fly-through field of view (degrees, 10..170)
    bool video = true;               ///< MP4 of the whole fly-over (needs the ffmpeg program)
    double videoStepMm = 2.0;        ///< distance between video frames along the centerline (mm)
    int videoFps = 25;               ///< video frame rate
    bool coverage = true;            ///< coverage of fly-over and fly-through, missed regions
    /// Coverage rays per view: coverage_px^2. 96 px every 3 mm gives the fractions of 192 px
    /// every 1 mm to within 0.1% on the phantoms, at a sixth of the time.
    int coveragePx = 96;
    double coverageStepMm = 3.0;     ///< distance between coverage views along the centerline (mm)
    bool review = true;              ///< review views for the fly-over's missed regions (review/)
    double reviewTarget = 0.995;     ///< review until fly-over plus review sees this fraction (0..1]
    /// 3: camera elevation from the framed half-width R(p), not D(p); 4: render split into
    /// steps (frames, flythrough, overviews, video, coverage), the video in video/; 5:
    /// loop-local OST.
    static constexpr int VERSION = 5;
};

struct PipelineParams {
    IngestParams ingest;
    SegmentParams segment;
    CenterlineParams centerline;
    MeshParams mesh;
    RenderParams render;
    PolypParams polyps;
};

/// Names of the stages, in pipeline order.
const std::vector<std::string>& stageNames();

/// Canonical JSON of one stage's parameters (keys sorted: nlohmann::json objects are).
nlohmann::json stageParamsToJson(const PipelineParams& params, const std::string& stage);
int stageVersion(const std::string& stage);

/// Applies a JSON object of the form {"stage": {"name": value, ...}, ...}.
/// @throw ParameterError naming the unknown stage/parameter or the bad value.
void applyParamsJson(PipelineParams& params, const nlohmann::json& config, const std::string& source);

/// Applies one "stage.name=value" assignment (value parsed as JSON when it can be, else as a
/// string). @throw ParameterError naming the parameter.
void applyParamAssignment(PipelineParams& params, const std::string& assignment);

/// Checks ranges that the type alone does not (positive sizes, fov in range, ...).
/// @throw ParameterError naming the parameter.
void validateParams(const PipelineParams& params);

/// A flat, human-readable description of every parameter with its default (for --help).
std::string describeParams();

} // namespace flyover
