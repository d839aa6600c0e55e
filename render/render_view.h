/// @file render_view.h
/// @brief Renders one view of a RayScene from a Camera: headlight diffuse shading with smooth
///        (interpolated vertex) normals, OST or plain, near clip plane per ray, optional depth
///        cue and supersampling. Callable per frame with any pose (for the interactive viewer);
///        per-pixel hits (depth, triangle) are kept on request so a pixel maps to a world point.
///        Does no file I/O.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"

#include <cstdint>
#include <vector>

namespace flyover {

/// How one-sided transparency discards back faces. Every method returns, per ray, the closest
/// hit on a face whose front (the lumen side) faces the ray, within [near, infinity); they
/// differ only in speed. bench/render_bench measures them.
enum class OstMethod {
    /// Per 16-ray packet: trace without a filter, then trace again, with the filter and from
    /// the first hit on, only the lanes whose first hit was a back face (rays that started
    /// outside the lumen). A task that meets a packet where most lanes need the second trace
    /// (a view from outside, e.g. the overview) filters the rest of its packets directly.
    Auto,
    /// Embree's context intersection filter on every candidate hit (one trace).
    Filter,
    /// Always the two-pass scheme of Auto, never switching to the filter.
    Retrace,
};

/// What a loop-local view passed through, counted over its pixel-centre rays (one per pixel):
/// `wallPixels` had a wall under the thesis' OST, `passedPixels` of them met another loop's
/// wall first, which was passed through.
struct LoopCounts {
    uint64_t wallPixels = 0;
    uint64_t passedPixels = 0;
    double passedShare() const { return wallPixels ? double(passedPixels) / double(wallPixels) : 0.0; }
};

struct RenderOptions {
    int widthPx = 512;        ///< image width (pixels, 1..65536)
    int heightPx = 512;       ///< image height (pixels, 1..65536)
    bool ost = true;          ///< discard back faces (one-sided transparency)
    int supersample = 1;      ///< n x n rays per pixel (1..16), averaged in linear colour
    /// Darken with depth: brightness / (1 + depth / depthCueRangeMm), depth counted from the near
    /// plane or from the scene's nearest bounding-box corner, whichever is farther.
    bool depthCue = false;
    /// Depth at which depthCue halves the brightness (mm); 0 = half the
    /// diagonal of the scene's bounding box.
    double depthCueRangeMm = 0.0;
    /// Shade with vertex normals interpolated across each triangle (true) or with the flat
    /// face normal (false). Visibility (the OST test) always uses the face's own normal.
    bool smoothShading = true;
    OstMethod ostMethod = OstMethod::Auto;
    /// Loop-local OST (with `ost` only); off by default.
    LoopWindow loop;
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

/// @throw ParameterError for sizes, supersampling or a camera out of range.
RgbImage renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                    HitImage* hits = nullptr);

/// The same, adding what a loop-local view passed through to `counts`.
void renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options, RgbImage& image,
                HitImage* hits, LoopCounts* counts);

/// The same into `image`, reusing its buffer (no allocation when the size is unchanged): for
/// loops over many frames.
void renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options, RgbImage& image,
                HitImage* hits = nullptr);

/// Width of the dark separator between the two views of a pair image (pixels).
constexpr int PAIR_GAP_PX = 4;

/// Pixels (RGB triples) that differ between two images; every pixel of the larger when their
/// sizes differ.
std::size_t differingPixels(const RgbImage& a, const RgbImage& b);

/// The pair image of two views, `left` | a `gapPx` dark separator | `right`, rendered in place:
/// the same pixels as sideBySide(renderView(left), renderView(right), gapPx) without the two
/// view images and their copy. Reuses `pair`'s buffer (no allocation when the size is unchanged).
/// @throw ParameterError as renderView, or for gapPx outside 0..65536
void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, int gapPx = PAIR_GAP_PX);
/// The same, with each view's hit image (as renderView gives it) in `leftHits` and `rightHits`.
void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, HitImage& leftHits, HitImage& rightHits, int gapPx = PAIR_GAP_PX);
/// The same, adding what the two loop-local views passed through to `counts`.
void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, LoopCounts* counts, int gapPx = PAIR_GAP_PX);

/// Only the hit image of the pixel-centre rays (no shading, no supersampling): the same rays
/// and the same OST and near-plane rules as renderView. For coverage and picking.
void traceHits(const RayScene& scene, const Camera& camera, const RenderOptions& options, HitImage& hits,
               LoopCounts* counts = nullptr);

/// The bare-throughput reference for benchmarks: the pixel-centre rays of renderView (same
/// origins, directions, near plane and 16-wide coherent packets), traced once without any
/// filter, shading or output. @return the number of rays that hit.
uint64_t traceBare(const RayScene& scene, const Camera& camera, int widthPx, int heightPx);

/// World position (mm) of the hit at pixel (x, y) of `hits` seen from `camera`, which must be
/// the camera that produced it. @throw ParameterError when the pixel is outside or missed.
Vec3d hitPointMm(const Camera& camera, const HitImage& hits, int x, int y);

/// Number of pixels of `hits` (seen from `camera`) whose hit point lies within `radiusMm` of
/// `centreMm`: how much of a known object (e.g. a polyp) a view shows.
int countHitsWithin(const Camera& camera, const HitImage& hits, const Vec3d& centreMm, double radiusMm);

/// Places two images side by side (same height) with a `gapPx` dark separator.
RgbImage sideBySide(const RgbImage& left, const RgbImage& right, int gapPx = PAIR_GAP_PX);

/// The same into `out`, reusing its buffer (no allocation when the size is unchanged); `out`
/// must be neither input.
void sideBySide(const RgbImage& left, const RgbImage& right, RgbImage& out, int gapPx = PAIR_GAP_PX);

} // namespace flyover
