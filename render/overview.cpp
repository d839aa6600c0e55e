#include "render/overview.h"
#include "volume/vec3.h"

#include "volume/error.h"

#include <algorithm>
#include <cmath>

namespace flyover {

namespace {

/// Blends `colour` into pixel (x, y) with weight a in [0, 1].
void blend(RgbImage& image, int x, int y, double a, const std::array<uint8_t, 3>& colour)
{
    if (x < 0 || y < 0 || x >= image.width || y >= image.height || !(a > 0)) return;
    a = std::min(a, 1.0);
    uint8_t* p = &image.rgb[(std::size_t(y) * std::size_t(image.width) + std::size_t(x)) * 3];
    for (int c = 0; c < 3; ++c)
        p[c] = uint8_t(std::lround(p[c] * (1.0 - a) + double(colour[std::size_t(c)]) * a));
}

} // namespace

const std::array<CanonicalView, 6>& canonicalViews()
{
    // LPS: +x patient left, +y posterior, +z superior.
    static const std::array<CanonicalView, 6> views = {{
        {"anterior", {0, 1, 0}, {0, 0, 1}},
        {"posterior", {0, -1, 0}, {0, 0, 1}},
        {"left", {-1, 0, 0}, {0, 0, 1}},
        {"right", {1, 0, 0}, {0, 0, 1}},
        {"superior", {0, 0, -1}, {0, -1, 0}},
        {"inferior", {0, 0, 1}, {0, -1, 0}},
    }};
    return views;
}

void drawMarker(RgbImage& image, const Camera& camera, const OverviewMarker& marker)
{
    if (image.width < 0 || image.height < 0 ||
        image.rgb.size() != std::size_t(image.width) * std::size_t(image.height) * 3)
        throw ParameterError("drawMarker: the image's pixel buffer does not match its size");
    if (!(marker.radiusMm >= 0) || !std::isfinite(marker.radiusMm))
        throw ParameterError("drawMarker: radiusMm must be finite and >= 0");
    const Vec3d d = marker.positionMm - camera.position;
    const double depth = dot(d, camera.forward);
    if (!(depth > 0) || image.width == 0 || image.height == 0) return;
    const double tanHalf = std::tan(0.5 * camera.fovDeg * PI / 180.0);
    const double aspect = double(image.width) / double(image.height);
    // Inverse of pixelDirection: image point (x, y) in pixels of the projected position.
    const double cx = (dot(d, camera.right) / (depth * tanHalf * aspect) + 1.0) * 0.5 * image.width;
    const double cy = (1.0 - dot(d, camera.up) / (depth * tanHalf)) * 0.5 * image.height;
    const double ringPx = std::max(4.0, marker.radiusMm / (depth * tanHalf) * 0.5 * image.height);
    const double dotPx = std::max(2.0, 0.012 * image.height);
    const double halfWidthPx = std::max(1.0, 0.004 * image.height);
    const double reach = ringPx + halfWidthPx + 2.0;
    const int x0 = int(std::floor(cx - reach)), x1 = int(std::ceil(cx + reach));
    const int y0 = int(std::floor(cy - reach)), y1 = int(std::ceil(cy + reach));
    for (int y = std::max(0, y0); y <= std::min(image.height - 1, y1); ++y)
        for (int x = std::max(0, x0); x <= std::min(image.width - 1, x1); ++x) {
            const double r = std::hypot(x + 0.5 - cx, y + 0.5 - cy);
            // Anti-aliased by coverage of a 1-pixel ramp at each edge.
            const double ring = std::clamp(halfWidthPx + 0.5 - std::fabs(r - ringPx), 0.0, 1.0);
            const double disc = marker.centreDot ? std::clamp(dotPx + 0.5 - r, 0.0, 1.0) : 0.0;
            blend(image, x, y, std::max(ring, disc), marker.colour);
        }
}

} // namespace flyover
