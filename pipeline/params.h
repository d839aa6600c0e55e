/// @file params.h
/// @brief Every stage's parameters, their canonical JSON form and strict parsing.
///
/// Parameter names in JSON, in `--set stage.name=value` and in config files are the
/// snake_case names listed by each visit function below. Parsing rejects unknown names
/// (a typo is an error, never silently ignored) and values of the wrong type or range.
#pragma once

#include "render/camera.h"
#include "surface/extract_surface.h"
#include "volume/centerline.h"
#include "volume/ingest.h"
#include "volume/segment.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// Parameters of the render stage (fly-over frames, overview).
struct RenderParams {
    int widthPx = 512;               ///< width of each fly-over view (pixels)
    int heightPx = 512;              ///< height of each fly-over view (pixels)
    double fovDeg = 90.0;            ///< fly-over field of view (degrees, 10..170)
    double rollDeg = 0.0;            ///< rotation of both cameras about the centerline (degrees)
    std::string direction = "right"; ///< travel towards image "right" or "left"
    double clipOffsetFraction = 0.5; ///< near plane at d - fraction*D(p) (thesis V.B)
    double clipOffsetMm = -1.0;      ///< if >= 0: near plane at d - this many mm instead
    double frameStepMm = 10.0;       ///< distance between saved frame pairs along the centerline
    int supersample = 1;             ///< n x n rays per pixel
    bool ost = true;                 ///< one-sided transparency (false: plain rendering)
    int overviewPx = 768;            ///< overview image size (pixels, square)
    static constexpr int VERSION = 1;
};

struct PipelineParams {
    IngestParams ingest;
    SegmentParams segment;
    CenterlineParams centerline;
    MeshParams mesh;
    RenderParams render;
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
