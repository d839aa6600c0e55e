/// @file inspect_params.h
/// @brief The parameters of `flyover inspect` (industrial CT of a solid part), by stage:
///        ingest, voids, surfaces and render, with their canonical JSON form and strict
///        parsing as for `flyover run` (colon/params.h): unknown names, wrong types and
///        out-of-range values are refused, naming the parameter.
#pragma once

#include "inspect/part_surface.h"
#include "inspect/voids.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// Ingest of a grey-value scan: no HU assumptions, every voxel kept (industrial scans have no
/// "air outside the body" to drop), any scalar type and range (uint16 as scanners write).
struct PartIngestParams {
    double voxelMm = 0.0;  ///< isotropic voxel size (mm); 0 = the smallest input spacing
    static constexpr int VERSION = 1;
};

/// The inspect render steps: overviews (six OST views, each beside a normal render, with the
/// size legend) and the turntable video.
struct PartRenderParams {
    int overviewPx = 512;       ///< each overview panel (pixels, square)
    int supersample = 2;        ///< n x n rays per pixel
    bool smoothShading = true;  ///< interpolated vertex normals
    bool depthCue = true;       ///< darken with depth
    bool video = true;          ///< the turntable MP4 (needs the ffmpeg program)
    int turntableFrames = 72;   ///< frames per turn (one turn about the superior axis)
    int videoFps = 24;          ///< video frame rate
    int videoPx = 384;          ///< each turntable panel (pixels, square)
    /// 2: visibility.json counts every ray (ost_rays), not only each pixel's centre ray.
    static constexpr int VERSION = 2;
};

struct InspectParams {
    PartIngestParams ingest;
    VoidParams voids;
    PartSurfaceParams surfaces;
    PartRenderParams render;
};

/// The parameter sections of inspect, in stage order: ingest, voids, surfaces, render.
const std::vector<std::string>& inspectSections();

/// Canonical JSON of one section (keys sorted). voids.threshold is null for Otsu.
nlohmann::json inspectParamsToJson(const InspectParams& params, const std::string& section);
int inspectSectionVersion(const std::string& section);

/// Applies {"section": {"name": value}}. @throw ParameterError naming the parameter.
void applyInspectParamsJson(InspectParams& params, const nlohmann::json& config, const std::string& source);
/// Applies "section.name=value". @throw ParameterError naming the parameter.
void applyInspectAssignment(InspectParams& params, const std::string& assignment);
/// Ranges. @throw ParameterError naming the parameter.
void validateInspectParams(const InspectParams& params);
/// Every parameter with its default, for `flyover params`.
std::string describeInspectParams();

} // namespace flyover
