/// @file render_view.h
/// @brief Renders one view of a RayScene from a Camera: headlight diffuse shading, OST or
///        plain, near clip plane per ray, optional supersampling. Callable per frame with
///        any pose (for the later interactive viewer); hit positions are kept on request.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"

#include <cstdint>
#include <vector>

namespace flyover {

struct RenderOptions {
    int widthPx = 512;
    int heightPx = 512;
    bool ost = true;          ///< discard back faces (one-sided transparency)
    int supersample = 1;      ///< n x n rays per pixel
    bool depthCue = false;    ///< darken with depth
    /// Depth beyond the near plane at which depthCue halves the brightness (mm); 0 = half the
    /// diagonal of the scene's bounding box.
    double depthCueRangeMm = 0.0;
};

struct RgbImage {
    int width = 0, height = 0;
    std::vector<uint8_t> rgb;  ///< row-major, top row first, 3 bytes per pixel
};

/// Per-pixel first hit of the centre ray (no supersampling): t < 0 means no hit.
struct HitImage {
    int width = 0, height = 0;
    std::vector<float> t;          ///< depth along camera forward (mm), -1 for a miss
    std::vector<uint32_t> primId;  ///< hit triangle, or UINT32_MAX for a miss
};

RgbImage renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                    HitImage* hits = nullptr);

/// Places two images side by side (same height) with a `gapPx` dark separator.
RgbImage sideBySide(const RgbImage& left, const RgbImage& right, int gapPx = 4);

} // namespace flyover
