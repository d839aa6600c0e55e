#include "render/render_view.h"

#include "render/ray_scene_impl.h"
#include "volume/error.h"

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

namespace {

constexpr double PI = 3.14159265358979323846;
constexpr int PACKET = 4;  ///< 4 x 4 pixel tiles = one 16-wide ray packet
constexpr int LANES = PACKET * PACKET;
constexpr int TILES_PER_TASK = 8;  ///< a task renders up to 8 x 8 tiles (32 x 32 pixels)
constexpr double GAMMA = 2.2;

/// Shading constants. Colours are given as displayed (gamma-encoded) and shaded in linear.
constexpr std::array<double, 3> TISSUE_DISPLAY = {0.93, 0.62, 0.55};
constexpr std::array<uint8_t, 3> BACKGROUND = {20, 20, 28};
constexpr std::array<uint8_t, 3> SEPARATOR = {6, 6, 8};
constexpr double AMBIENT = 0.15;
constexpr double DIFFUSE = 0.85;

double toLinear(double display) { return std::pow(display, GAMMA); }

/// Linear -> 8-bit display value, rounded to nearest in display space, without a pow per
/// channel (that cost a third of the frame time): byte b covers the linear interval
/// [((b - 0.5) / 255)^gamma, ((b + 0.5) / 255)^gamma). A table over uniform bins gives the
/// byte at the start of x's bin; a few steps up the interval bounds make the result exact.
class DisplayEncoder {
public:
    DisplayEncoder()
    {
        for (int b = 0; b < 255; ++b) mUpper[std::size_t(b)] = toLinear((b + 0.5) / 255.0);
        for (std::size_t i = 0; i < BINS; ++i) {
            const double x = double(i) / double(BINS);
            mStart[i] = uint8_t(std::upper_bound(mUpper.begin(), mUpper.end(), x) - mUpper.begin());
        }
    }
    uint8_t operator()(double linear) const
    {
        if (!(linear > 0.0)) return 0;
        if (linear >= 1.0) return 255;
        std::size_t b = mStart[std::size_t(linear * double(BINS))];
        while (b < mUpper.size() && linear >= mUpper[b]) ++b;
        return uint8_t(b);
    }

private:
    static constexpr std::size_t BINS = 4096;
    std::array<double, 255> mUpper;  ///< exclusive upper bound of byte b's interval
    std::array<uint8_t, BINS> mStart;
};

void validate(const Camera& camera, const RenderOptions& options)
{
    std::ostringstream msg;
    if (!(options.widthPx > 0 && options.heightPx > 0) || options.widthPx > 65536 ||
        options.heightPx > 65536) {
        msg << "RenderOptions: widthPx and heightPx must be in 1..65536, got " << options.widthPx
            << " x " << options.heightPx;
    } else if (!(options.supersample >= 1 && options.supersample <= 16)) {
        msg << "RenderOptions.supersample must be in 1..16, got " << options.supersample;
    } else if (!(options.depthCueRangeMm >= 0.0) || !std::isfinite(options.depthCueRangeMm)) {
        msg << "RenderOptions.depthCueRangeMm must be >= 0, got " << options.depthCueRangeMm;
    } else if (!(camera.fovDeg > 0.0 && camera.fovDeg < 180.0)) {
        msg << "Camera.fovDeg must be in (0, 180) degrees, got " << camera.fovDeg;
    } else if (!(camera.nearMm >= 0.0) || !std::isfinite(camera.nearMm)) {
        msg << "Camera.nearMm must be finite and >= 0, got " << camera.nearMm;
    } else if (!(std::fabs(length(camera.forward) - 1.0) < 1e-6 &&
                 std::fabs(length(camera.up) - 1.0) < 1e-6 &&
                 std::fabs(length(camera.right) - 1.0) < 1e-6)) {
        msg << "Camera: forward, up and right must be unit vectors";
    } else {
        return;
    }
    throw ParameterError(msg.str());
}

} // namespace

RgbImage renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                    HitImage* hits)
{
    validate(camera, options);
    const int width = options.widthPx;
    const int height = options.heightPx;
    const int ss = options.supersample;
    const RTCScene rtcScene = scene.impl().scene;

    const double tanHalf = std::tan(0.5 * camera.fovDeg * PI / 180.0);
    const double aspect = double(width) / double(height);
    // dir = forward + sx * tan(fov/2) * aspect * right + sy * tan(fov/2) * up, sx, sy in [-1, 1]:
    // dot(dir, forward) == 1, so t is depth and tnear == nearMm is a near plane.
    const Vec3d stepX = camera.right * (2.0 * tanHalf * aspect / width);
    const Vec3d stepY = camera.up * (-2.0 * tanHalf / height);
    const Vec3d corner = camera.forward - camera.right * (tanHalf * aspect) + camera.up * tanHalf;

    const std::array<double, 3> tissue = {toLinear(TISSUE_DISPLAY[0]), toLinear(TISSUE_DISPLAY[1]),
                                          toLinear(TISSUE_DISPLAY[2])};
    const std::array<double, 3> background = {toLinear(BACKGROUND[0] / 255.0),
                                              toLinear(BACKGROUND[1] / 255.0),
                                              toLinear(BACKGROUND[2] / 255.0)};
    static const DisplayEncoder toDisplay;
    const double cueRangeMm = options.depthCueRangeMm > 0.0
                                  ? options.depthCueRangeMm
                                  : std::max(1e-6, 0.5 * distance(scene.boundsMin(), scene.boundsMax()));

    RgbImage image;
    image.width = width;
    image.height = height;
    image.rgb.assign(std::size_t(width) * std::size_t(height) * 3, 0);
    if (hits) {
        hits->width = width;
        hits->height = height;
        hits->t.assign(std::size_t(width) * std::size_t(height), -1.0f);
        hits->primId.assign(std::size_t(width) * std::size_t(height), std::numeric_limits<uint32_t>::max());
    }

    // The centre ray of a pixel is one of the n x n samples when n is odd; otherwise it is
    // traced in an extra pass that only fills the hit image.
    const bool centreIsSample = (ss % 2) == 1;
    const int centreSample = ss / 2;
    const int passes = ss * ss + ((hits && !centreIsSample) ? 1 : 0);
    const double weight = 1.0 / double(ss * ss);

    const int tilesX = (width + PACKET - 1) / PACKET;
    const int tilesY = (height + PACKET - 1) / PACKET;

    auto renderTiles = [&](const tbb::blocked_range2d<int>& range) {
        const DenormalsFlushed flushed;
        RTCIntersectContext context;
        initIntersectContext(context, options.ost, true);
        RTCRayHit16 packet;
        alignas(64) int valid[LANES];

        for (int ty = range.rows().begin(); ty != range.rows().end(); ++ty) {
            for (int tx = range.cols().begin(); tx != range.cols().end(); ++tx) {
                std::array<std::array<double, 3>, LANES> sum{};
                for (int pass = 0; pass < passes; ++pass) {
                    const bool centreOnly = pass == ss * ss;
                    const int sa = centreOnly ? 0 : pass % ss;
                    const int sb = centreOnly ? 0 : pass / ss;
                    const double ox = centreOnly ? 0.5 : (sa + 0.5) / ss;
                    const double oy = centreOnly ? 0.5 : (sb + 0.5) / ss;
                    const bool recordHits =
                        hits && (centreOnly || (centreIsSample && sa == centreSample && sb == centreSample));

                    for (int i = 0; i < LANES; ++i) {
                        const int px = tx * PACKET + i % PACKET;
                        const int py = ty * PACKET + i / PACKET;
                        valid[i] = (px < width && py < height) ? -1 : 0;
                        const Vec3d dir = corner + stepX * (px + ox) + stepY * (py + oy);
                        packet.ray.org_x[i] = float(camera.position.x);
                        packet.ray.org_y[i] = float(camera.position.y);
                        packet.ray.org_z[i] = float(camera.position.z);
                        packet.ray.dir_x[i] = float(dir.x);
                        packet.ray.dir_y[i] = float(dir.y);
                        packet.ray.dir_z[i] = float(dir.z);
                        packet.ray.tnear[i] = float(camera.nearMm);
                        packet.ray.tfar[i] = std::numeric_limits<float>::infinity();
                        packet.ray.time[i] = 0.f;
                        packet.ray.mask[i] = 0xFFFFFFFFu;
                        packet.ray.id[i] = unsigned(i);
                        packet.ray.flags[i] = 0;
                        packet.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
                        packet.hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
                        packet.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
                    }
                    rtcIntersect16(valid, rtcScene, &context, &packet);

                    for (int i = 0; i < LANES; ++i) {
                        if (!valid[i]) continue;
                        const bool isHit = packet.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
                        if (recordHits && isHit) {
                            const std::size_t pix =
                                std::size_t(ty * PACKET + i / PACKET) * std::size_t(width) +
                                std::size_t(tx * PACKET + i % PACKET);
                            hits->t[pix] = packet.ray.tfar[i];
                            hits->primId[pix] = packet.hit.primID[i];
                        }
                        if (centreOnly) continue;
                        if (!isHit) {
                            for (int c = 0; c < 3; ++c) sum[i][c] += background[c];
                            continue;
                        }
                        const Vec3d dir{packet.ray.dir_x[i], packet.ray.dir_y[i], packet.ray.dir_z[i]};
                        const Vec3d ng{packet.hit.Ng_x[i], packet.hit.Ng_y[i], packet.hit.Ng_z[i]};
                        // Headlight: the light sits at the eye, so |cos| between ray and normal
                        // (one square root and one division: this loop runs per ray).
                        const double norms = std::sqrt(dot(dir, dir) * dot(ng, ng));
                        const double cosine = norms > 0.0 ? std::fabs(dot(dir, ng)) / norms : 0.0;
                        double shade = AMBIENT + DIFFUSE * cosine;
                        if (options.depthCue) {
                            const double depth = std::max(0.0, double(packet.ray.tfar[i]) - camera.nearMm);
                            shade /= 1.0 + depth / cueRangeMm;
                        }
                        for (int c = 0; c < 3; ++c) sum[i][c] += tissue[c] * shade;
                    }
                }
                for (int i = 0; i < LANES; ++i) {
                    const int px = tx * PACKET + i % PACKET;
                    const int py = ty * PACKET + i / PACKET;
                    if (px >= width || py >= height) continue;
                    uint8_t* out = &image.rgb[(std::size_t(py) * std::size_t(width) + std::size_t(px)) * 3];
                    for (int c = 0; c < 3; ++c) out[c] = toDisplay(sum[i][c] * weight);
                }
            }
        }
    };

    // simple_partitioner: every task gets at most TILES_PER_TASK x TILES_PER_TASK tiles, and the
    // result per pixel does not depend on how the image was split.
    tbb::parallel_for(tbb::blocked_range2d<int>(0, tilesY, TILES_PER_TASK, 0, tilesX, TILES_PER_TASK),
                      renderTiles, tbb::simple_partitioner());
    return image;
}

RgbImage sideBySide(const RgbImage& left, const RgbImage& right, int gapPx)
{
    auto consistent = [](const RgbImage& im) {
        return im.width >= 0 && im.height >= 0 &&
               im.rgb.size() == std::size_t(im.width) * std::size_t(im.height) * 3;
    };
    if (!consistent(left) || !consistent(right)) {
        throw ParameterError("sideBySide: an image's pixel buffer does not match its size");
    }
    if (left.height != right.height) {
        std::ostringstream msg;
        msg << "sideBySide: images must have the same height, got " << left.height << " and "
            << right.height;
        throw ParameterError(msg.str());
    }
    if (!(gapPx >= 0)) {
        std::ostringstream msg;
        msg << "sideBySide: gapPx must be >= 0, got " << gapPx;
        throw ParameterError(msg.str());
    }
    RgbImage out;
    out.width = left.width + gapPx + right.width;
    out.height = left.height;
    out.rgb.resize(std::size_t(out.width) * std::size_t(out.height) * 3);
    for (int y = 0; y < out.height; ++y) {
        uint8_t* row = out.rgb.data() + std::size_t(y) * std::size_t(out.width) * 3;
        std::copy_n(left.rgb.data() + std::size_t(y) * std::size_t(left.width) * 3, std::size_t(left.width) * 3, row);
        uint8_t* gap = row + std::size_t(left.width) * 3;
        for (int x = 0; x < gapPx; ++x)
            for (int c = 0; c < 3; ++c) gap[x * 3 + c] = SEPARATOR[std::size_t(c)];
        std::copy_n(right.rgb.data() + std::size_t(y) * std::size_t(right.width) * 3, std::size_t(right.width) * 3,
                    gap + std::size_t(gapPx) * 3);
    }
    return out;
}

} // namespace flyover
