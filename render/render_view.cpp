#include "render/render_view.h"
#include "volume/vec3.h"

#include "render/headlight_shade.h"
#include "render/ray_scene_impl.h"
#include "render/view_rays.h"
#include "volume/error.h"

#include <tbb/blocked_range2d.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

namespace {

constexpr int TILES_PER_TASK = 8;  ///< a task renders up to 8 x 8 tiles (32 x 32 pixels)
constexpr double GAMMA = 2.2;
constexpr uint32_t NO_HIT = std::numeric_limits<uint32_t>::max();
constexpr float INF_F = std::numeric_limits<float>::infinity();

/// Shading constants. Colours are given as displayed (gamma-encoded) and shaded in linear.
constexpr std::array<double, 3> TISSUE_DISPLAY = {0.93, 0.62, 0.55};
constexpr std::array<uint8_t, 3> BACKGROUND = {20, 20, 28};
constexpr std::array<uint8_t, 3> SEPARATOR = {6, 6, 8};

/// Writes `gapPx` separator pixels from `out` on (one row of a pair image's gap).
void fillSeparator(uint8_t* out, std::size_t gapPx)
{
    for (std::size_t x = 0; x < gapPx; ++x)
        for (std::size_t c = 0; c < 3; ++c) out[x * 3 + c] = SEPARATOR[c];
}
using detail::headlightShade;
using detail::headlightShadeLanes;

double toLinear(double display) { return std::pow(display, GAMMA); }

/// Linear -> 8-bit display value, rounded to nearest in display space, without a pow per
/// channel (that cost a third of the frame time): byte b covers the linear interval
/// [((b - 0.5) / 255)^gamma, ((b + 0.5) / 255)^gamma). A table over uniform bins gives the
/// byte at the start of x's bin; a few steps up the interval bounds make the result exact.
class DisplayEncoder {
public:
    DisplayEncoder()
    {
        for (int b = 0; b < 255; ++b) mUpper[std::size_t(b)] = float(toLinear((b + 0.5) / 255.0));
        for (std::size_t i = 0; i < BINS; ++i) {
            const float x = float(i) / float(BINS);
            mStart[i] = uint8_t(std::upper_bound(mUpper.begin(), mUpper.end(), x) - mUpper.begin());
        }
    }
    uint8_t operator()(float linear) const
    {
        if (!(linear > 0.0f)) return 0;
        if (linear >= 1.0f) return 255;
        std::size_t b = mStart[std::size_t(linear * float(BINS))];
        while (b < mUpper.size() && linear >= mUpper[b]) ++b;
        return uint8_t(b);
    }

private:
    static constexpr std::size_t BINS = 4096;
    std::array<float, 255> mUpper;  ///< exclusive upper bound of byte b's interval
    std::array<uint8_t, BINS> mStart;
};

void validate(const Camera& camera, int width, int height, int supersample, double depthCueRangeMm)
{
    std::ostringstream msg;
    if (!(width > 0 && height > 0) || width > 65536 || height > 65536) {
        msg << "RenderOptions: widthPx and heightPx must be in 1..65536, got " << width << " x " << height;
    } else if (!(supersample >= 1 && supersample <= 16)) {
        msg << "RenderOptions.supersample must be in 1..16, got " << supersample;
    } else if (!(depthCueRangeMm >= 0.0) || !std::isfinite(depthCueRangeMm)) {
        msg << "RenderOptions.depthCueRangeMm must be >= 0, got " << depthCueRangeMm;
    } else if (!(camera.fovDeg > 0.0 && camera.fovDeg < 180.0)) {
        msg << "Camera.fovDeg must be in (0, 180) degrees, got " << camera.fovDeg;
    } else if (!(camera.nearMm >= 0.0) || !std::isfinite(camera.nearMm)) {
        msg << "Camera.nearMm must be finite and >= 0, got " << camera.nearMm;
    } else if (!(std::fabs(length(camera.forward) - 1.0) < 1e-6 &&
                 std::fabs(length(camera.up) - 1.0) < 1e-6 &&
                 std::fabs(length(camera.right) - 1.0) < 1e-6)) {
        msg << "Camera: forward, up and right must be unit vectors";
    } else if (!(std::isfinite(camera.position.x) && std::isfinite(camera.position.y) &&
                 std::isfinite(camera.position.z))) {
        msg << "Camera.position must be finite";
    } else {
        return;
    }
    throw ParameterError(msg.str());
}

/// A loop window names one owner per triangle of the scene.
void validateLoop(const RayScene& scene, const LoopWindow& loop)
{
    if (!loop.active()) return;
    if (loop.ownerArcMm->size() != scene.triangleCount()) {
        std::ostringstream msg;
        msg << "RenderOptions.loop: " << loop.ownerArcMm->size() << " triangle owners for a scene of "
            << scene.triangleCount() << " triangles";
        throw ParameterError(msg.str());
    }
    if (!std::isfinite(loop.arcMm) || !std::isfinite(loop.reachMm)) throw ParameterError("RenderOptions.loop: arc and reach must be finite");
}

/// Traces 16-wide packets with OST done by one of the exact methods of OstMethod, and with
/// loop-local OST when the options' window is active. One per task: it keeps the Auto method's
/// switch to the filter for the rest of the task.
class PacketTracer {
public:
    PacketTracer(RTCScene scene, const RenderOptions& options)
        : mScene(scene), mOst(options.ost), mMethod(options.ostMethod), mLoopOn(options.ost && options.loop.active())
    {
        initIntersectContext(mPlain, false, true);
        initIntersectContext(mFilter, true, true);
        initIntersectContext(mLoop.context, true, true);
        if (mLoopOn) {
            mLoop.context.filter = &loopOstFilter;
            mLoop.ownerArc = options.loop.ownerArcMm->data();
            mLoop.arcLo = float(options.loop.arcMm - options.loop.reachMm);
            mLoop.arcHi = float(options.loop.arcMm + options.loop.reachMm);
        }
        std::fill(std::begin(mLoop.passedT), std::end(mLoop.passedT), INF_F);
    }

    void trace(int* valid, RTCRayHit16& packet)
    {
        if (!mOst) {
            rtcIntersect16(valid, mScene, &mPlain, &packet);
            return;
        }
        RTCIntersectContext* filter = &mFilter;
        if (mLoopOn) {
            std::fill(std::begin(mLoop.passedT), std::end(mLoop.passedT), INF_F);
            filter = &mLoop.context;
        }
        if (mMethod == OstMethod::Filter || mFilterOnly) {
            rtcIntersect16(valid, mScene, filter, &packet);
            return;
        }
        rtcIntersect16(valid, mScene, &mPlain, &packet);
        // A lane whose closest hit is a back face started outside the lumen: its OST answer is
        // the closest front face beyond that hit. Tracing it again with the filter from just
        // before that hit gives exactly what the filter alone would have given, because no face
        // of any kind lies closer. The same holds for a front face of another loop.
        alignas(64) int again[LANES];
        int lanes = 0, retraced = 0;
        for (int i = 0; i < LANES; ++i) {
            again[i] = 0;
            if (!valid[i]) continue;
            ++lanes;
            if (packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
            // The filter's own test, in the same float arithmetic (ray_scene.cpp ostFilter).
            const float d = packet.ray.dir_x[i] * packet.hit.Ng_x[i] + packet.ray.dir_y[i] * packet.hit.Ng_y[i] +
                            packet.ray.dir_z[i] * packet.hit.Ng_z[i];
            bool pass = d > 0.0f;
            if (!pass && mLoopOn) {
                const float arc = mLoop.ownerArc[packet.hit.primID[i]];
                pass = arc < mLoop.arcLo || arc > mLoop.arcHi;
            }
            if (pass) {
                again[i] = -1;
                packet.ray.tnear[i] = std::nextafter(packet.ray.tfar[i], 0.0f);
                packet.ray.tfar[i] = INF_F;
                packet.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
                packet.hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
                ++retraced;
            }
        }
        if (retraced > 0) rtcIntersect16(again, mScene, filter, &packet);
        if (mMethod == OstMethod::Auto && 2 * retraced > lanes) mFilterOnly = true;
    }

    /// After trace(): adds lane i's pixel to `counts` (a wall under the thesis' OST; passed
    /// when another loop's wall lay in front of what the view shows).
    void count(const RTCRayHit16& packet, int i, LoopCounts& counts) const
    {
        const bool isHit = packet.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
        const bool passed = mLoop.passedT[i] < (isHit ? packet.ray.tfar[i] : INF_F);
        counts.wallPixels += (isHit || passed) ? 1 : 0;
        counts.passedPixels += passed ? 1 : 0;
    }
    bool loopOn() const { return mLoopOn; }

private:
    RTCScene mScene;
    bool mOst;
    OstMethod mMethod;
    bool mLoopOn;
    bool mFilterOnly = false;
    RTCIntersectContext mPlain;
    RTCIntersectContext mFilter;
    LoopContext mLoop;
};

/// Per-task loop counts, summed when the view is done.
using TaskCounts = tbb::combinable<LoopCounts>;

void addCounts(TaskCounts& tasks, LoopCounts* counts)
{
    if (!counts) return;
    tasks.combine_each([counts](const LoopCounts& c) {
        counts->wallPixels += c.wallPixels;
        counts->passedPixels += c.passedPixels;
    });
}

/// Headlight diffuse shading of one hit: ambient + diffuse * |cos| between the ray and the
/// shading normal (the light sits at the eye), divided by the depth cue.
struct Shader {
    const RayScene::Impl& im;
    bool smooth;
    float invCueRangeMm;  ///< 0: no depth cue
    float cueStartMm;     ///< depth at which the depth cue starts

    Shader(const RayScene::Impl& impl, bool smoothShading, float invCueRange, float cueStart)
        : im(impl), smooth(smoothShading), invCueRangeMm(invCueRange), cueStartMm(cueStart)
    {
    }

    /// Shade in [0, 1] of lane i, which must have hit.
    float shade(const RTCRayHit16& packet, int i) const
    {
        float n[3];
        normal(packet, i, n);
        return shadeFrom(packet.ray.dir_x[i], packet.ray.dir_y[i], packet.ray.dir_z[i], n[0], n[1], n[2],
                         packet.ray.tfar[i]);
    }

    /// Shades of all 16 lanes (misses get an arbitrary value): the gathers of the normals first,
    /// then the arithmetic in a loop the compiler vectorises.
    void shadePacket(const RTCRayHit16& packet, float* shades) const
    {
        alignas(64) float nx[LANES], ny[LANES], nz[LANES];
        for (int i = 0; i < LANES; ++i) {
            if (packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) {
                nx[i] = ny[i] = nz[i] = 0.0f;
                continue;
            }
            float n[3];
            normal(packet, i, n);
            nx[i] = n[0];
            ny[i] = n[1];
            nz[i] = n[2];
        }
        headlightShadeLanes(packet.ray.dir_x, packet.ray.dir_y, packet.ray.dir_z, nx, ny, nz, packet.ray.tfar, LANES,
                            invCueRangeMm, cueStartMm, shades);
    }

private:
    void normal(const RTCRayHit16& packet, int i, float* n) const
    {
        if (smooth) {
            const uint32_t* tri = &im.indices[3 * std::size_t(packet.hit.primID[i])];
            const float u = packet.hit.u[i], v = packet.hit.v[i], w = 1.0f - u - v;
            const auto& n0 = im.vertexNormals[tri[0]];
            const auto& n1 = im.vertexNormals[tri[1]];
            const auto& n2 = im.vertexNormals[tri[2]];
            n[0] = w * n0.x + u * n1.x + v * n2.x;
            n[1] = w * n0.y + u * n1.y + v * n2.y;
            n[2] = w * n0.z + u * n1.z + v * n2.z;
        } else {
            n[0] = packet.hit.Ng_x[i];
            n[1] = packet.hit.Ng_y[i];
            n[2] = packet.hit.Ng_z[i];
        }
    }

    float shadeFrom(float dx, float dy, float dz, float nx, float ny, float nz, float t) const
    {
        return headlightShade(dx, dy, dz, nx, ny, nz, t, invCueRangeMm, cueStartMm);
    }
};

/// Tissue colour as a function of the shade, in linear and as display bytes.
class ColourTables {
public:
    static constexpr int STEPS = 4096;  ///< shade resolution of the byte table: < 0.4 byte error

    ColourTables()
    {
        for (int c = 0; c < 3; ++c) {
            mTissue[std::size_t(c)] = float(toLinear(TISSUE_DISPLAY[std::size_t(c)]));
            mBackground[std::size_t(c)] = float(toLinear(BACKGROUND[std::size_t(c)] / 255.0));
        }
        for (int q = 0; q <= STEPS; ++q)
            for (int c = 0; c < 3; ++c)
                mBytes[std::size_t(q)][std::size_t(c)] = mEncode(mTissue[std::size_t(c)] * float(q) / float(STEPS));
    }
    /// Display bytes of tissue lit with `shade` in [0, 1].
    const uint8_t* tissueBytes(float shade) const
    {
        const int q = int(std::min(1.0f, std::max(0.0f, shade)) * float(STEPS) + 0.5f);
        return mBytes[std::size_t(q)].data();
    }
    std::array<float, 3> tissueLinear(float shade) const
    {
        return {mTissue[0] * shade, mTissue[1] * shade, mTissue[2] * shade};
    }
    const std::array<float, 3>& backgroundLinear() const { return mBackground; }
    uint8_t encode(float linear) const { return mEncode(linear); }

private:
    DisplayEncoder mEncode;
    std::array<float, 3> mTissue{}, mBackground{};
    std::array<std::array<uint8_t, 3>, STEPS + 1> mBytes{};
};

void resetHits(HitImage& hits, int width, int height)
{
    hits.width = width;
    hits.height = height;
    hits.t.assign(std::size_t(width) * std::size_t(height), -1.0f);
    hits.primId.assign(std::size_t(width) * std::size_t(height), NO_HIT);
}

/// Runs `body(range)` over the image's 4 x 4 tiles in tasks of at most 8 x 8 tiles.
/// simple_partitioner: tasks never exceed the grain, and the split (hence the Auto method's
/// per-task switch) does not depend on the number of threads.
template <typename Body> void forEachTileRange(int width, int height, const Body& body)
{
    const int tilesX = (width + PACKET - 1) / PACKET;
    const int tilesY = (height + PACKET - 1) / PACKET;
    tbb::parallel_for(tbb::blocked_range2d<int>(0, tilesY, TILES_PER_TASK, 0, tilesX, TILES_PER_TASK), body,
                      tbb::simple_partitioner());
}

} // namespace

RgbImage renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options,
                    HitImage* hits)
{
    RgbImage image;
    renderView(scene, camera, options, image, hits);
    return image;
}

namespace {

/// Renders the view into `rgb`, whose rows are `rowPixels` pixels apart: pixel (x, y) of the
/// view is rgb[3 * (y * rowPixels + x)]. The caller has validated the options.
void renderInto(const RayScene& scene, const Camera& camera, const RenderOptions& options, uint8_t* rgb,
                std::size_t rowPixels, HitImage* hits, LoopCounts* counts)
{
    const int width = options.widthPx;
    const int height = options.heightPx;
    const int ss = options.supersample;
    const RayScene::Impl& im = scene.impl();
    const ViewRays rays(camera, width, height);
    static const ColourTables colours;
    // The depth cue starts at the near plane or at the scene's nearest corner, whichever is
    // farther: a camera far outside (overview) is not dimmed by the empty space in front.
    double nearestCornerMm = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 8; ++k) {
        const Vec3d lo = scene.boundsMin(), hi = scene.boundsMax();
        const Vec3d corner{(k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z};
        nearestCornerMm = std::min(nearestCornerMm, dot(corner - camera.position, camera.forward));
    }
    const double cueStartMm = std::max(camera.nearMm, nearestCornerMm);
    const Shader shader(im, options.smoothShading,
                        options.depthCue ? float(1.0 / (options.depthCueRangeMm > 0.0
                                                            ? options.depthCueRangeMm
                                                            : std::max(1e-6, 0.5 * distance(scene.boundsMin(),
                                                                                            scene.boundsMax()))))
                                         : 0.0f,
                        float(cueStartMm));

    if (hits) resetHits(*hits, width, height);

    // The centre ray of a pixel is one of the n x n samples when n is odd; otherwise it is
    // traced in an extra pass that only fills the hit image.
    const bool centreIsSample = (ss % 2) == 1;
    const int centreSample = ss / 2;
    const int passes = ss * ss + ((hits && !centreIsSample) ? 1 : 0);
    const float weight = 1.0f / float(ss * ss);
    TaskCounts taskCounts;

    forEachTileRange(width, height, [&](const tbb::blocked_range2d<int>& range) {
        const DenormalsFlushed flushed;
        PacketTracer tracer(im.scene, options);
        LoopCounts& loopCounts = taskCounts.local();
        RTCRayHit16 packet;
        alignas(64) int valid[LANES];

        for (int ty = range.rows().begin(); ty != range.rows().end(); ++ty) {
            for (int tx = range.cols().begin(); tx != range.cols().end(); ++tx) {
                if (ss == 1) {
                    // One ray per pixel: straight from the shade to display bytes by table.
                    rays.fill(tx, ty, 0.5f, 0.5f, valid, packet);
                    tracer.trace(valid, packet);
                    alignas(64) float shades[LANES];
                    shader.shadePacket(packet, shades);
                    for (int i = 0; i < LANES; ++i) {
                        if (!valid[i]) continue;
                        if (counts && tracer.loopOn()) tracer.count(packet, i, loopCounts);
                        const std::size_t row = std::size_t(ty * PACKET + i / PACKET);
                        const std::size_t column = std::size_t(tx * PACKET + i % PACKET);
                        const std::size_t pix = row * std::size_t(width) + column;
                        uint8_t* out = rgb + (row * rowPixels + column) * 3;
                        if (packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) {
                            out[0] = BACKGROUND[0];
                            out[1] = BACKGROUND[1];
                            out[2] = BACKGROUND[2];
                            continue;
                        }
                        if (hits) {
                            hits->t[pix] = packet.ray.tfar[i];
                            hits->primId[pix] = packet.hit.primID[i];
                        }
                        const uint8_t* c = colours.tissueBytes(shades[i]);
                        out[0] = c[0];
                        out[1] = c[1];
                        out[2] = c[2];
                    }
                    continue;
                }
                std::array<std::array<float, 3>, LANES> sum{};
                for (int pass = 0; pass < passes; ++pass) {
                    const bool centreOnly = pass == ss * ss;
                    const int sa = centreOnly ? 0 : pass % ss;
                    const int sb = centreOnly ? 0 : pass / ss;
                    const float ox = centreOnly ? 0.5f : (float(sa) + 0.5f) / float(ss);
                    const float oy = centreOnly ? 0.5f : (float(sb) + 0.5f) / float(ss);
                    const bool recordHits =
                        hits && (centreOnly || (centreIsSample && sa == centreSample && sb == centreSample));
                    const bool countPass = counts && tracer.loopOn() && pass == 0;

                    rays.fill(tx, ty, ox, oy, valid, packet);
                    tracer.trace(valid, packet);

                    for (int i = 0; i < LANES; ++i) {
                        if (!valid[i]) continue;
                        if (countPass) tracer.count(packet, i, loopCounts);
                        const bool isHit = packet.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
                        if (recordHits && isHit) {
                            const std::size_t pix = std::size_t(ty * PACKET + i / PACKET) * std::size_t(width) +
                                                    std::size_t(tx * PACKET + i % PACKET);
                            hits->t[pix] = packet.ray.tfar[i];
                            hits->primId[pix] = packet.hit.primID[i];
                        }
                        if (centreOnly) continue;
                        const std::array<float, 3> lin =
                            isHit ? colours.tissueLinear(shader.shade(packet, i)) : colours.backgroundLinear();
                        for (int c = 0; c < 3; ++c) sum[std::size_t(i)][std::size_t(c)] += lin[std::size_t(c)];
                    }
                }
                for (int i = 0; i < LANES; ++i) {
                    const int px = tx * PACKET + i % PACKET;
                    const int py = ty * PACKET + i / PACKET;
                    if (px >= width || py >= height) continue;
                    uint8_t* out = rgb + (std::size_t(py) * rowPixels + std::size_t(px)) * 3;
                    for (int c = 0; c < 3; ++c)
                        out[c] = colours.encode(sum[std::size_t(i)][std::size_t(c)] * weight);
                }
            }
        }
    });
    addCounts(taskCounts, counts);
}

} // namespace

void renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options, RgbImage& image,
                HitImage* hits, LoopCounts* counts)
{
    validate(camera, options.widthPx, options.heightPx, options.supersample, options.depthCueRangeMm);
    validateLoop(scene, options.loop);
    image.width = options.widthPx;
    image.height = options.heightPx;
    image.rgb.resize(std::size_t(image.width) * std::size_t(image.height) * 3);  // every pixel is written
    renderInto(scene, camera, options, image.rgb.data(), std::size_t(image.width), hits, counts);
}

void renderView(const RayScene& scene, const Camera& camera, const RenderOptions& options, RgbImage& image,
                HitImage* hits)
{
    renderView(scene, camera, options, image, hits, nullptr);
}

std::size_t differingPixels(const RgbImage& a, const RgbImage& b)
{
    if (a.width != b.width || a.height != b.height || a.rgb.size() != b.rgb.size())
        return std::size_t(std::max(a.width * a.height, b.width * b.height));
    std::size_t n = 0;
    for (std::size_t i = 0; i + 2 < a.rgb.size(); i += 3)
        n += (a.rgb[i] != b.rgb[i] || a.rgb[i + 1] != b.rgb[i + 1] || a.rgb[i + 2] != b.rgb[i + 2]) ? 1 : 0;
    return n;
}

namespace {

void renderPairInto(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                    RgbImage& pair, HitImage* leftHits, HitImage* rightHits, int gapPx, LoopCounts* counts = nullptr)
{
    validateLoop(scene, options.loop);
    validate(left, options.widthPx, options.heightPx, options.supersample, options.depthCueRangeMm);
    validate(right, options.widthPx, options.heightPx, options.supersample, options.depthCueRangeMm);
    if (!(gapPx >= 0 && gapPx <= 65536)) {
        std::ostringstream msg;
        msg << "renderPair: gapPx must be in 0..65536, got " << gapPx;
        throw ParameterError(msg.str());
    }
    const std::size_t w = std::size_t(options.widthPx), h = std::size_t(options.heightPx), gap = std::size_t(gapPx);
    pair.width = int(2 * w + gap);
    pair.height = int(h);
    const std::size_t row = 2 * w + gap;
    pair.rgb.resize(row * h * 3);  // every pixel is written
    for (std::size_t y = 0; y < h; ++y) fillSeparator(pair.rgb.data() + (y * row + w) * 3, gap);
    renderInto(scene, left, options, pair.rgb.data(), row, leftHits, counts);
    renderInto(scene, right, options, pair.rgb.data() + (w + gap) * 3, row, rightHits, counts);
}

} // namespace

void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, int gapPx)
{
    renderPairInto(scene, left, right, options, pair, nullptr, nullptr, gapPx);
}

void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, HitImage& leftHits, HitImage& rightHits, int gapPx)
{
    renderPairInto(scene, left, right, options, pair, &leftHits, &rightHits, gapPx);
}

void renderPair(const RayScene& scene, const Camera& left, const Camera& right, const RenderOptions& options,
                RgbImage& pair, LoopCounts* counts, int gapPx)
{
    renderPairInto(scene, left, right, options, pair, nullptr, nullptr, gapPx, counts);
}

void traceHits(const RayScene& scene, const Camera& camera, const RenderOptions& options, HitImage& hits,
               LoopCounts* counts)
{
    validate(camera, options.widthPx, options.heightPx, 1, options.depthCueRangeMm);
    validateLoop(scene, options.loop);
    TaskCounts taskCounts;
    const int width = options.widthPx;
    const int height = options.heightPx;
    const ViewRays rays(camera, width, height);
    resetHits(hits, width, height);
    forEachTileRange(width, height, [&](const tbb::blocked_range2d<int>& range) {
        const DenormalsFlushed flushed;
        PacketTracer tracer(scene.impl().scene, options);
        LoopCounts& loopCounts = taskCounts.local();
        RTCRayHit16 packet;
        alignas(64) int valid[LANES];
        for (int ty = range.rows().begin(); ty != range.rows().end(); ++ty) {
            for (int tx = range.cols().begin(); tx != range.cols().end(); ++tx) {
                rays.fill(tx, ty, 0.5f, 0.5f, valid, packet);
                tracer.trace(valid, packet);
                for (int i = 0; i < LANES; ++i) {
                    if (valid[i] && counts && tracer.loopOn()) tracer.count(packet, i, loopCounts);
                    if (!valid[i] || packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
                    const std::size_t pix = std::size_t(ty * PACKET + i / PACKET) * std::size_t(width) +
                                            std::size_t(tx * PACKET + i % PACKET);
                    hits.t[pix] = packet.ray.tfar[i];
                    hits.primId[pix] = packet.hit.primID[i];
                }
            }
        }
    });
    addCounts(taskCounts, counts);
}

uint64_t traceBare(const RayScene& scene, const Camera& camera, int widthPx, int heightPx)
{
    validate(camera, widthPx, heightPx, 1, 0.0);
    const ViewRays rays(camera, widthPx, heightPx);
    tbb::combinable<uint64_t> hitCount([] { return uint64_t(0); });
    forEachTileRange(widthPx, heightPx, [&](const tbb::blocked_range2d<int>& range) {
        const DenormalsFlushed flushed;
        RTCIntersectContext context;
        initIntersectContext(context, false, true);
        RTCRayHit16 packet;
        alignas(64) int valid[LANES];
        uint64_t n = 0;
        for (int ty = range.rows().begin(); ty != range.rows().end(); ++ty) {
            for (int tx = range.cols().begin(); tx != range.cols().end(); ++tx) {
                rays.fill(tx, ty, 0.5f, 0.5f, valid, packet);
                rtcIntersect16(valid, scene.impl().scene, &context, &packet);
                for (int i = 0; i < LANES; ++i)
                    n += (valid[i] && packet.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID) ? 1 : 0;
            }
        }
        hitCount.local() += n;
    });
    return hitCount.combine([](uint64_t a, uint64_t b) { return a + b; });
}

Vec3d hitPointMm(const Camera& camera, const HitImage& hits, int x, int y)
{
    if (!(x >= 0 && y >= 0 && x < hits.width && y < hits.height) ||
        hits.t.size() != std::size_t(hits.width) * std::size_t(hits.height)) {
        std::ostringstream msg;
        msg << "hitPointMm: pixel (" << x << ", " << y << ") outside the " << hits.width << " x " << hits.height
            << " hit image";
        throw ParameterError(msg.str());
    }
    const float t = hits.t[std::size_t(y) * std::size_t(hits.width) + std::size_t(x)];
    if (!(t >= 0.0f)) {
        std::ostringstream msg;
        msg << "hitPointMm: pixel (" << x << ", " << y << ") has no hit";
        throw ParameterError(msg.str());
    }
    return camera.position + pixelDirection(camera, hits.width, hits.height, x + 0.5, y + 0.5) * double(t);
}

int countHitsWithin(const Camera& camera, const HitImage& hits, const Vec3d& centreMm, double radiusMm)
{
    if (hits.t.size() != std::size_t(hits.width) * std::size_t(hits.height))
        throw ParameterError("countHitsWithin: the hit image's buffer does not match its size");
    const double r2 = radiusMm * radiusMm;
    int count = 0;
    for (int y = 0; y < hits.height; ++y)
        for (int x = 0; x < hits.width; ++x) {
            const float t = hits.t[std::size_t(y) * std::size_t(hits.width) + std::size_t(x)];
            if (!(t >= 0.0f)) continue;
            const Vec3d p =
                camera.position + pixelDirection(camera, hits.width, hits.height, x + 0.5, y + 0.5) * double(t);
            const Vec3d d = p - centreMm;
            count += dot(d, d) <= r2 ? 1 : 0;
        }
    return count;
}

void sideBySide(const RgbImage& left, const RgbImage& right, RgbImage& out, int gapPx)
{
    auto consistent = [](const RgbImage& im) {
        return im.width >= 0 && im.height >= 0 &&
               im.rgb.size() == std::size_t(im.width) * std::size_t(im.height) * 3;
    };
    if (!consistent(left) || !consistent(right)) {
        throw ParameterError("sideBySide: an image's pixel buffer does not match its size");
    }
    if (&out == &left || &out == &right) throw ParameterError("sideBySide: the output must not be an input image");
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
    out.width = left.width + gapPx + right.width;
    out.height = left.height;
    out.rgb.resize(std::size_t(out.width) * std::size_t(out.height) * 3);
    for (int y = 0; y < out.height; ++y) {
        uint8_t* row = out.rgb.data() + std::size_t(y) * std::size_t(out.width) * 3;
        std::copy_n(left.rgb.data() + std::size_t(y) * std::size_t(left.width) * 3, std::size_t(left.width) * 3, row);
        uint8_t* gap = row + std::size_t(left.width) * 3;
        fillSeparator(gap, std::size_t(gapPx));
        std::copy_n(right.rgb.data() + std::size_t(y) * std::size_t(right.width) * 3, std::size_t(right.width) * 3,
                    gap + std::size_t(gapPx) * 3);
    }
}

RgbImage sideBySide(const RgbImage& left, const RgbImage& right, int gapPx)
{
    RgbImage out;
    sideBySide(left, right, out, gapPx);
    return out;
}

} // namespace flyover
