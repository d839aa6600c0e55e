#include "render/flyover_path.h"
#include "volume/vec3.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <sstream>

namespace flyover {

namespace {

/// tan(fov/2) of the checked parameters.
double checkedTanHalf(const FlyoverParams& params, const FrameRadiusOptions& options)
{
    if (!(params.fovDeg > 0.0 && params.fovDeg < 180.0))
        throw ParameterError("flyoverFrameRadii: fovDeg must be in (0, 180)");
    if (options.fanRays < 8 || !(options.marginFraction >= 0) || !(options.windowMm >= 0) || !(options.smoothMm >= 0))
        throw ParameterError("flyoverFrameRadii: fanRays >= 8 and non-negative margin, window and smoothing needed");
    return std::tan(0.5 * params.fovDeg * PI / 180.0);
}

/// The farthest a fan ray of `p` goes: 4 * cap, cap = 2 D(p) + 5 mm.
double capOf(const CenterlinePoint& p) { return 2.0 * std::max(p.radiusMm, 0.0) + 5.0; }

/// The half-width one cross-section needs, before the maximum and the Gaussian (with the margin).
double needAt(const RayScene& scene, const CenterlinePoint& p, const FlyoverParams& params,
              const FrameRadiusOptions& options, double tanHalf, const BoxMm* box = nullptr,
              std::atomic<bool>* within = nullptr)
{
    const double d = std::max(p.radiusMm, 0.0);
    double r = d;
    if (!p.bridged) {
        const FlyoverAxes ax = flyoverAxes(p, params.rollDeg);
        const double cap = capOf(p);
        for (int k = 0; k < options.fanRays; ++k) {
            const double a = 2.0 * PI * k / options.fanRays;  // k = 0: along +b, the lateral axis
            const double ca = std::cos(a), sa = std::sin(a);
            const Vec3d dir = ax.b * ca + ax.n * sa;
            const RayHit hit = scene.intersect(p.positionMm, dir, 0.0, 4.0 * cap, false);
            if (box && !(box->contains(p.positionMm) && box->contains(p.positionMm + dir * (hit.hit ? hit.t : 4.0 * cap))))
                *within = false;
            if (!hit.hit) continue;  // an open end: nothing to frame that way
            const double lateral = hit.t * std::fabs(ca), depth = hit.t * std::fabs(sa);
            r = std::max(r, std::min(cap, lateral - depth * tanHalf));
        }
    }
    return r * (1.0 + options.marginFraction);
}

/// The running maximum's half-window and the Gaussian's weights, in centerline points.
struct Smoothing {
    long window = 0;
    bool gaussian = false;
    long half = 0;
    std::vector<double> weights;

    Smoothing(const Centerline& centerline, const FrameRadiusOptions& options)
    {
        const double step = centerline.stepMm > 0 ? centerline.stepMm : 1.0;
        window = long(std::lround(options.windowMm / step));
        gaussian = options.smoothMm > 0;
        if (!gaussian) return;
        const double sigma = options.smoothMm / step;
        half = long(std::ceil(3 * sigma));
        weights.resize(std::size_t(2 * half + 1));
        for (long k = -half; k <= half; ++k)
            weights[std::size_t(k + half)] = std::exp(-0.5 * double(k * k) / (sigma * sigma));
    }

    long reach() const { return window + (gaussian ? half : 0); }

    /// R(i) from need[j - first] for every j within reach of i.
    double radiusAt(const std::vector<double>& need, std::size_t first, std::size_t i,
                    const Centerline& centerline) const
    {
        const std::size_t n = centerline.points.size();
        auto widened = [&](std::size_t j) {
            const std::size_t lo = j >= std::size_t(window) ? j - std::size_t(window) : 0,
                              hi = std::min(n - 1, j + std::size_t(window));
            return *std::max_element(need.begin() + long(lo - first), need.begin() + long(hi - first) + 1);
        };
        if (!gaussian) return widened(i);
        double sum = 0, wsum = 0;
        for (long k = -half; k <= half; ++k) {
            const long j = long(i) + k;
            if (j < 0 || j >= long(n)) continue;
            sum += weights[std::size_t(k + half)] * widened(std::size_t(j));
            wsum += weights[std::size_t(k + half)];
        }
        return std::max(sum / wsum, centerline.points[i].radiusMm);
    }
};

void checkIndex(const Centerline& centerline, std::size_t index, const char* where)
{
    if (index >= centerline.points.size()) {
        std::ostringstream msg;
        msg << where << ": centerline index " << index << " past the centerline's " << centerline.points.size()
            << " points";
        throw ParameterError(msg.str());
    }
}

std::pair<std::size_t, std::size_t> reachOf(const Centerline& centerline, std::size_t index, const Smoothing& s)
{
    const auto r = std::size_t(s.reach());
    return {index >= r ? index - r : 0, std::min(centerline.points.size() - 1, index + r)};
}

/// The triangles whose `keep` flag is set, three vertex indices each, in order.
std::vector<uint32_t> gather(const std::vector<uint32_t>& triangleIndices, const std::vector<uint8_t>& keep)
{
    std::size_t count = 0;
    for (const uint8_t k : keep) count += k;
    std::vector<uint32_t> out;
    out.reserve(3 * count);
    for (std::size_t f = 0; f < keep.size(); ++f)
        if (keep[f])
            out.insert(out.end(), triangleIndices.begin() + long(3 * f), triangleIndices.begin() + long(3 * f + 3));
    return out;
}

} // namespace

std::vector<double> flyoverFrameRadii(const RayScene& scene, const Centerline& centerline,
                                      const FlyoverParams& params, const FrameRadiusOptions& options)
{
    const double tanHalf = checkedTanHalf(params, options);
    const std::size_t n = centerline.points.size();
    std::vector<double> need(n, 0.0);
    tbb::parallel_for(std::size_t(0), n,
                      [&](std::size_t i) { need[i] = needAt(scene, centerline.points[i], params, options, tanHalf); });
    const Smoothing smoothing(centerline, options);
    std::vector<double> out(n);
    for (std::size_t i = 0; i < n; ++i) out[i] = smoothing.radiusAt(need, 0, i, centerline);
    return out;
}

std::pair<std::size_t, std::size_t> frameRadiusReach(const Centerline& centerline, std::size_t index,
                                                     const FrameRadiusOptions& options)
{
    checkIndex(centerline, index, "frameRadiusReach");
    return reachOf(centerline, index, Smoothing(centerline, options));
}

namespace {

/// flyoverFrameRadiusAt, with the fan rays checked against `box` when one is given.
double frameRadiusAt(const RayScene& scene, const Centerline& centerline, const FlyoverParams& params,
                     std::size_t index, const FrameRadiusOptions& options, const BoxMm* box, std::atomic<bool>* within)
{
    const double tanHalf = checkedTanHalf(params, options);
    checkIndex(centerline, index, "flyoverFrameRadiusAt");
    const Smoothing smoothing(centerline, options);
    const auto [first, last] = reachOf(centerline, index, smoothing);
    std::vector<double> need(last - first + 1);
    tbb::parallel_for(first, last + 1, [&](std::size_t j) {
        need[j - first] = needAt(scene, centerline.points[j], params, options, tanHalf, box, within);
    });
    return smoothing.radiusAt(need, first, index, centerline);
}

} // namespace

double flyoverFrameRadiusAt(const RayScene& scene, const Centerline& centerline, const FlyoverParams& params,
                            std::size_t index, const FrameRadiusOptions& options)
{
    return frameRadiusAt(scene, centerline, params, index, options, nullptr, nullptr);
}

double flyoverFrameRadiusAt(const RayScene& scene, const Centerline& centerline, const FlyoverParams& params,
                            std::size_t index, const FrameRadiusOptions& options, const BoxMm& box, bool& within)
{
    std::atomic<bool> inside{true};
    const double r = frameRadiusAt(scene, centerline, params, index, options, &box, &inside);
    within = inside.load();
    return r;
}

std::vector<uint32_t> frameRadiusTriangles(const std::vector<float>& verticesXyz,
                                           const std::vector<uint32_t>& triangleIndices,
                                           const Centerline& centerline, const FlyoverParams& params,
                                           std::size_t index, const FrameRadiusOptions& options, double marginMm)
{
    checkedTanHalf(params, options);
    checkIndex(centerline, index, "frameRadiusTriangles");
    checkTriangleArrays(verticesXyz, triangleIndices, "frameRadiusTriangles");
    if (!std::isfinite(marginMm)) throw ParameterError("frameRadiusTriangles: marginMm must be finite");
    const auto [first, last] = reachOf(centerline, index, Smoothing(centerline, options));
    // The cross-section planes of the points that cast rays (bridged points cast none).
    struct Plane {
        Vec3d centre, normal;
        double offset, reach;
    };
    std::vector<Plane> planes;
    for (std::size_t j = first; j <= last; ++j) {
        const CenterlinePoint& p = centerline.points[j];
        if (p.bridged) continue;
        const Vec3d t = flyoverAxes(p, params.rollDeg).t;
        planes.push_back({p.positionMm, t, dot(t, p.positionMm), 4.0 * capOf(p) + marginMm});
    }
    const std::size_t nv = verticesXyz.size() / 3, nf = triangleIndices.size() / 3;
    std::vector<uint8_t> keep(nf, 0);
    auto vertexAt = [&](uint32_t i) {
        const float* v = &verticesXyz[3 * std::size_t(i)];
        return Vec3d{v[0], v[1], v[2]};
    };
    // 64 planes at a time: per vertex, a bit for "beyond the plane's slab" on either side.
    std::vector<uint64_t> above(nv), below(nv);
    for (std::size_t p0 = 0; p0 < planes.size(); p0 += 64) {
        const std::size_t count = std::min<std::size_t>(64, planes.size() - p0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nv, 8192), [&](const auto& range) {
            for (std::size_t i = range.begin(); i != range.end(); ++i) {
                const Vec3d v = vertexAt(uint32_t(i));
                uint64_t a = 0, b = 0;
                for (std::size_t k = 0; k < count; ++k) {
                    const Plane& pl = planes[p0 + k];
                    const double s = dot(pl.normal, v) - pl.offset;
                    a |= uint64_t(s > marginMm) << k;
                    b |= uint64_t(s < -marginMm) << k;
                }
                above[i] = a;
                below[i] = b;
            }
        });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 8192), [&](const auto& range) {
            for (std::size_t f = range.begin(); f != range.end(); ++f) {
                if (keep[f]) continue;
                const uint32_t* t = &triangleIndices[3 * f];
                uint64_t straddles = ~(above[t[0]] & above[t[1]] & above[t[2]]) &
                                     ~(below[t[0]] & below[t[1]] & below[t[2]]);
                if (count < 64) straddles &= (uint64_t(1) << count) - 1;
                if (!straddles) continue;
                // Every point of the triangle lies within its longest edge of each vertex: it is
                // beyond the rays' reach when its nearest vertex is farther than reach + edge.
                const Vec3d a = vertexAt(t[0]), b = vertexAt(t[1]), c = vertexAt(t[2]);
                const double edge = std::max({length(b - a), length(c - b), length(a - c)});
                for (std::size_t k = 0; k < count && !keep[f]; ++k) {
                    if (!((straddles >> k) & 1)) continue;
                    const Plane& pl = planes[p0 + k];
                    const double nearest =
                        std::min({length(a - pl.centre), length(b - pl.centre), length(c - pl.centre)});
                    if (nearest <= pl.reach + edge) keep[f] = 1;
                }
            }
        });
    }
    return gather(triangleIndices, keep);
}

std::vector<uint32_t> frustumTriangles(const std::vector<float>& verticesXyz,
                                       const std::vector<uint32_t>& triangleIndices,
                                       const std::vector<Camera>& cameras, int widthPx, int heightPx,
                                       double marginMm)
{
    checkTriangleArrays(verticesXyz, triangleIndices, "frustumTriangles");
    if (cameras.empty() || cameras.size() > 3)
        throw ParameterError("frustumTriangles: one to three cameras needed");
    if (!(widthPx > 0 && heightPx > 0)) throw ParameterError("frustumTriangles: widthPx and heightPx must be > 0");
    if (!std::isfinite(marginMm)) throw ParameterError("frustumTriangles: marginMm must be finite");
    // Five planes per camera, in the camera's frame (X right, Y up, Z forward = depth):
    // X <= Z tx + mx, -X <= Z tx + mx, the same for Y with ty, and Z >= near - margin; mx is the
    // margin measured perpendicular to the side plane.
    struct Frustum {
        Vec3d position, right, up, forward;
        double tx, ty, mx, my, nearZ;
    };
    std::vector<Frustum> frusta;
    for (const Camera& c : cameras) {
        if (!(c.fovDeg > 0.0 && c.fovDeg < 180.0)) throw ParameterError("frustumTriangles: fovDeg must be in (0, 180)");
        const double ty = std::tan(0.5 * c.fovDeg * PI / 180.0) * 1.001;
        const double tx = ty * double(widthPx) / double(heightPx);
        frusta.push_back({c.position, c.right, c.up, c.forward, tx, ty, marginMm * std::sqrt(1 + tx * tx),
                          marginMm * std::sqrt(1 + ty * ty), c.nearMm - marginMm});
    }
    const std::size_t nv = verticesXyz.size() / 3, nf = triangleIndices.size() / 3;
    // Per vertex, five bits per camera: outside the plane.
    std::vector<uint16_t> outside(nv);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nv, 8192), [&](const auto& range) {
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            const float* v = &verticesXyz[3 * i];
            uint16_t bits = 0;
            for (std::size_t k = 0; k < frusta.size(); ++k) {
                const Frustum& fr = frusta[k];
                const Vec3d d = Vec3d{v[0], v[1], v[2]} - fr.position;
                const double x = dot(d, fr.right), y = dot(d, fr.up), z = dot(d, fr.forward);
                const unsigned b = unsigned(x > z * fr.tx + fr.mx) | unsigned(-x > z * fr.tx + fr.mx) << 1 |
                                   unsigned(y > z * fr.ty + fr.my) << 2 | unsigned(-y > z * fr.ty + fr.my) << 3 |
                                   unsigned(z < fr.nearZ) << 4;
                bits = uint16_t(bits | b << (5 * k));
            }
            outside[i] = bits;
        }
    });
    std::vector<uint8_t> keep(nf, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 8192), [&](const auto& range) {
        for (std::size_t f = range.begin(); f != range.end(); ++f) {
            const uint32_t* t = &triangleIndices[3 * f];
            const unsigned all = unsigned(outside[t[0]] & outside[t[1]] & outside[t[2]]);
            for (std::size_t k = 0; k < frusta.size(); ++k)
                if (((all >> (5 * k)) & 31u) == 0) keep[f] = 1;
        }
    });
    return gather(triangleIndices, keep);
}

} // namespace flyover
