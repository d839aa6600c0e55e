#include "inspect/part_render.h"

#include "volume/error.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <sstream>

namespace flyover {

namespace {

constexpr double GAMMA = 2.2;
constexpr double AMBIENT = 0.25, DIFFUSE = 0.75;

double toLinear(uint8_t display) { return std::pow(double(display) / 255.0, GAMMA); }
uint8_t toDisplay(double linear)
{
    const double d = std::pow(std::clamp(linear, 0.0, 1.0), 1.0 / GAMMA);
    return uint8_t(std::lround(d * 255.0));
}

/// Colour stops of the size scale, small to large.
constexpr std::array<Rgb8, 6> SIZE_STOPS{{{49, 110, 210}, {0, 185, 195}, {110, 200, 60},
                                          {245, 205, 30}, {245, 120, 20}, {215, 30, 30}}};

/// 5x7 glyphs, one byte per row (bit 4 = leftmost column).
const std::map<char, std::array<uint8_t, 7>>& font()
{
    static const std::map<char, std::array<uint8_t, 7>> glyphs{
        {'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}}, {'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
        {'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}}, {'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
        {'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}}, {'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
        {'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}}, {'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
        {'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}}, {'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
        {'.', {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}}, {'-', {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}},
        {'(', {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}}, {')', {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}},
        {'O', {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}}, {'S', {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E}},
        {'T', {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}}, {'a', {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F}},
        {'c', {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E}}, {'d', {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F}},
        {'e', {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E}}, {'i', {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E}},
        {'k', {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12}}, {'l', {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}},
        {'m', {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11}}, {'n', {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11}},
        {'o', {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E}}, {'p', {0x00, 0x00, 0x1E, 0x11, 0x1E, 0x10, 0x10}},
        {'r', {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10}}, {'s', {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E}},
        {'t', {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06}}, {'v', {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04}},
    };
    return glyphs;
}

void setPixel(RgbImage& image, int x, int y, const Rgb8& c)
{
    if (x < 0 || y < 0 || x >= image.width || y >= image.height) return;
    uint8_t* p = image.rgb.data() + (std::size_t(y) * std::size_t(image.width) + std::size_t(x)) * 3;
    p[0] = c[0];
    p[1] = c[1];
    p[2] = c[2];
}

std::string formatMm(double mm)
{
    char text[32];
    std::snprintf(text, sizeof text, mm < 10 ? "%.2f" : "%.1f", mm);
    return text;
}

} // namespace

double SizeColourScale::position(double diameterMm) const
{
    if (!(maxMm > minMm) || !(minMm > 0)) return 1.0;
    const double t = std::log(std::max(diameterMm, 1e-12) / minMm) / std::log(maxMm / minMm);
    return std::clamp(t, 0.0, 1.0);
}

Rgb8 SizeColourScale::colourAt(double t)
{
    t = std::clamp(t, 0.0, 1.0) * double(SIZE_STOPS.size() - 1);
    const std::size_t i = std::min(std::size_t(t), SIZE_STOPS.size() - 2);
    const double f = t - double(i);
    Rgb8 c;
    for (std::size_t k = 0; k < 3; ++k)
        c[k] = uint8_t(std::lround((1 - f) * SIZE_STOPS[i][k] + f * SIZE_STOPS[i + 1][k]));
    return c;
}

Rgb8 SizeColourScale::colour(double diameterMm) const { return colourAt(position(diameterMm)); }

RgbImage renderFaceColours(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                           const std::vector<Rgb8>& faceColours, HitImage* hits, std::vector<uint32_t>* sampleHits)
{
    const int w = options.widthPx, h = options.heightPx, n = options.supersample;
    if (!(w >= 1 && h >= 1 && w <= 65536 && h <= 65536))
        throw ParameterError("renderFaceColours: width and height must be in 1..65536");
    if (!(n >= 1 && n <= 16)) throw ParameterError("renderFaceColours: supersample must be in 1..16");
    if (faceColours.size() != scene.triangleCount())
        throw ParameterError("renderFaceColours: " + std::to_string(faceColours.size()) + " colours for " +
                             std::to_string(scene.triangleCount()) + " triangles");
    // Depth cue reference: the scene's nearest bounding-box corner, half the diagonal.
    const Vec3d lo = scene.boundsMin(), hi = scene.boundsMax();
    double nearest = std::numeric_limits<double>::infinity();
    for (int c = 0; c < 8; ++c) {
        const Vec3d corner{(c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z};
        nearest = std::min(nearest, dot(corner - camera.position, camera.forward));
    }
    const double cueRange = options.depthCueRangeMm > 0 ? options.depthCueRangeMm : 0.5 * length(hi - lo);
    const double cueStart = std::max(nearest, camera.nearMm);

    // Linear values by display byte (a table, not a copy per face: the scene has millions of
    // faces and a turntable renders it hundreds of times).
    std::array<double, 256> linear;
    for (std::size_t b = 0; b < 256; ++b) linear[b] = toLinear(uint8_t(b));
    std::array<double, 3> background;
    for (std::size_t k = 0; k < 3; ++k) background[k] = toLinear(PART_BACKGROUND[k]);

    RgbImage image;
    image.width = w;
    image.height = h;
    image.rgb.assign(std::size_t(w) * std::size_t(h) * 3, 0);
    if (hits) {
        hits->width = w;
        hits->height = h;
        hits->t.assign(std::size_t(w) * std::size_t(h), -1.0f);
        hits->primId.assign(std::size_t(w) * std::size_t(h), std::numeric_limits<uint32_t>::max());
    }
    if (sampleHits) sampleHits->assign(std::size_t(w) * std::size_t(h) * std::size_t(n * n), std::numeric_limits<uint32_t>::max());
    tbb::parallel_for(0, h, [&](int y) {
        for (int x = 0; x < w; ++x) {
            std::array<double, 3> sum{0, 0, 0};
            for (int sy = 0; sy < n; ++sy)
                for (int sx = 0; sx < n; ++sx) {
                    const bool centre = n == 1 || (sx == n / 2 && sy == n / 2);
                    const double px = x + (n == 1 ? 0.5 : (sx + 0.5) / n), py = y + (n == 1 ? 0.5 : (sy + 0.5) / n);
                    const Vec3d dir = pixelDirection(camera, w, h, px, py);
                    const RayHit hit = scene.intersect(camera.position, dir, camera.nearMm,
                                                       std::numeric_limits<double>::infinity(), options.ost);
                    if (sampleHits && hit.hit)
                        (*sampleHits)[(std::size_t(y) * std::size_t(w) + std::size_t(x)) * std::size_t(n * n) +
                                      std::size_t(sy * n + sx)] = hit.primId;
                    if (!hit.hit) {
                        for (std::size_t k = 0; k < 3; ++k) sum[k] += background[k];
                        continue;
                    }
                    if (centre && hits) {
                        const std::size_t i = std::size_t(y) * std::size_t(w) + std::size_t(x);
                        hits->t[i] = float(hit.t);
                        hits->primId[i] = hit.primId;
                    }
                    const Vec3d nrm = scene.shadingNormal(hit.primId, hit.u, hit.v, options.smoothShading);
                    double shade = AMBIENT + DIFFUSE * std::fabs(dot(nrm, normalize(dir)));
                    if (options.depthCue) shade /= 1.0 + std::max(0.0, hit.t - cueStart) / cueRange;
                    for (std::size_t k = 0; k < 3; ++k) sum[k] += shade * linear[faceColours[hit.primId][k]];
                }
            uint8_t* p = image.rgb.data() + (std::size_t(y) * std::size_t(w) + std::size_t(x)) * 3;
            for (std::size_t k = 0; k < 3; ++k) p[k] = toDisplay(sum[k] / double(n * n));
        }
    });
    return image;
}

std::array<int, 2> textSize(const std::string& text, int scale)
{
    return {int(text.size()) * 6 * scale - (text.empty() ? 0 : scale), 7 * scale};
}

void drawText(RgbImage& image, int x, int y, const std::string& text, const Rgb8& colour, int scale)
{
    const auto& glyphs = font();
    for (std::size_t i = 0; i < text.size(); ++i) {
        const auto g = glyphs.find(text[i]);
        if (g == glyphs.end()) continue;
        const int gx = x + int(i) * 6 * scale;
        for (int row = 0; row < 7; ++row)
            for (int col = 0; col < 5; ++col)
                if (g->second[std::size_t(row)] & (0x10 >> col))
                    for (int dy = 0; dy < scale; ++dy)
                        for (int dx = 0; dx < scale; ++dx)
                            setPixel(image, gx + col * scale + dx, y + row * scale + dy, colour);
    }
}

RgbImage sizeLegendPanel(const SizeColourScale& scale, int widthPx, int heightPx)
{
    if (widthPx < 16 || heightPx < 64) throw ParameterError("sizeLegendPanel: the panel is too small");
    RgbImage panel;
    panel.width = widthPx;
    panel.height = heightPx;
    panel.rgb.resize(std::size_t(widthPx) * std::size_t(heightPx) * 3);
    for (std::size_t i = 0; i < panel.rgb.size(); i += 3)
        for (std::size_t k = 0; k < 3; ++k) panel.rgb[i + k] = PART_BACKGROUND[k];
    const Rgb8 text{230, 230, 230};
    drawText(panel, 6, 8, "void", text, 1);
    drawText(panel, 6, 18, "diameter", text, 1);
    drawText(panel, 6, 28, "(mm)", text, 1);
    const int top = 48, bottom = heightPx - 16, barX = 8, barW = 14;
    for (int y = top; y <= bottom; ++y) {
        const double t = bottom > top ? double(bottom - y) / double(bottom - top) : 1.0;
        const Rgb8 c = SizeColourScale::colourAt(scale.maxMm > scale.minMm ? t : 1.0);
        for (int x = barX; x < barX + barW; ++x) setPixel(panel, x, y, c);
    }
    // Labels at the ends and at three points between (geometric steps, as the scale is).
    const int labels = scale.maxMm > scale.minMm ? 5 : 1;
    for (int i = 0; i < labels; ++i) {
        const double t = labels == 1 ? 1.0 : double(i) / double(labels - 1);
        const double mm = labels == 1 ? scale.maxMm : scale.minMm * std::pow(scale.maxMm / scale.minMm, t);
        const int y = int(std::lround(bottom - t * (bottom - top)));
        for (int x = barX + barW; x < barX + barW + 4; ++x) setPixel(panel, x, y, text);
        drawText(panel, barX + barW + 6, y - 3, formatMm(mm), text, 1);
    }
    return panel;
}

} // namespace flyover
