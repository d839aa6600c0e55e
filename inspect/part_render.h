/// @file part_render.h
/// @brief Renders a part with per-triangle colours (the inspect overviews and turntable):
///        the part's surfaces in grey, each internal void in the colour of its size, OST or
///        normal (opaque), with the hit triangle per pixel kept so that the pixels of each void
///        can be counted. Also the size colour scale, its legend and a small bitmap font for
///        labels drawn into images. No file I/O, no OpenVDB.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"
#include "render/render_view.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

using Rgb8 = std::array<uint8_t, 3>;

/// Colour of the part's own surfaces, and of the background.
inline constexpr Rgb8 PART_GREY{190, 190, 190};
inline constexpr Rgb8 PART_BACKGROUND{22, 22, 26};

/// Void size -> colour: equivalent diameter on a logarithmic scale from minMm (blue) to maxMm
/// (red), through teal, green, yellow and orange. A single size (minMm == maxMm) is red.
struct SizeColourScale {
    double minMm = 1, maxMm = 1;
    /// 0..1 position of a diameter on the scale (clamped).
    double position(double diameterMm) const;
    Rgb8 colour(double diameterMm) const;
    /// The colour at position t in [0, 1].
    static Rgb8 colourAt(double t);
};

/// One view with a colour per triangle (`faceColours[primId]`, one per scene triangle):
/// headlight diffuse shading (ambient 0.25) with the scene's smooth normals, `options.ost`
/// discarding back faces, n x n supersampling averaged in linear colour, optional depth cue
/// (brightness / (1 + depth beyond the scene's nearest bounding-box corner / half its diagonal)).
/// `hits` receives the centre ray's hit per pixel; `sampleHits` every ray's hit triangle
/// (UINT32_MAX for a miss), n x n per pixel, pixels row by row: a void smaller than a pixel
/// that no centre ray meets is still seen by the samples that meet it.
/// @throw ParameterError for a size, supersampling or colour count out of range.
RgbImage renderFaceColours(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                           const std::vector<Rgb8>& faceColours, HitImage* hits = nullptr,
                           std::vector<uint32_t>* sampleHits = nullptr);

/// Width and height (pixels) of `text` drawn by drawText at `scale`.
std::array<int, 2> textSize(const std::string& text, int scale);
/// Draws `text` (digits, '.', '-', '(', ')', ' ', and the letters of "OST normal void diameter
/// mm pcks"; other characters are blank) with a 5x7 bitmap font, `scale` pixels per font
/// pixel, top-left corner at (x, y); clipped at the image's edges.
void drawText(RgbImage& image, int x, int y, const std::string& text, const Rgb8& colour, int scale = 1);

/// A legend panel for the size colours: a vertical colour bar from the smallest listed void's
/// diameter (bottom) to the largest (top), labelled in mm, under the title "void diameter".
/// `heightPx` is the panel's height (the image's it stands beside).
RgbImage sizeLegendPanel(const SizeColourScale& scale, int widthPx, int heightPx);

} // namespace flyover
