#include "render/flyover_path.h"

#include "volume/error.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace flyover {

std::vector<double> flyoverFrameRadii(const RayScene& scene, const Centerline& centerline,
                                      const FlyoverParams& params, const FrameRadiusOptions& options)
{
    if (!(params.fovDeg > 0.0 && params.fovDeg < 180.0))
        throw ParameterError("flyoverFrameRadii: fovDeg must be in (0, 180)");
    if (options.fanRays < 8 || !(options.marginFraction >= 0) || !(options.windowMm >= 0) || !(options.smoothMm >= 0))
        throw ParameterError("flyoverFrameRadii: fanRays >= 8 and non-negative margin, window and smoothing needed");
    constexpr double PI = 3.14159265358979323846;
    const double tanHalf = std::tan(0.5 * params.fovDeg * PI / 180.0);
    const std::size_t n = centerline.points.size();
    std::vector<double> need(n, 0.0);
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        const CenterlinePoint& p = centerline.points[i];
        const double d = std::max(p.radiusMm, 0.0);
        double r = d;
        if (!p.bridged) {
            const FlyoverAxes ax = flyoverAxes(p, params.rollDeg);
            const double cap = 2.0 * d + 5.0;
            for (int k = 0; k < options.fanRays; ++k) {
                const double a = 2.0 * PI * k / options.fanRays;  // k = 0: along +b, the lateral axis
                const double ca = std::cos(a), sa = std::sin(a);
                const Vec3d dir = ax.b * ca + ax.n * sa;
                const RayHit hit = scene.intersect(p.positionMm, dir, 0.0, 4.0 * cap, false);
                if (!hit.hit) continue;  // an open end: nothing to frame that way
                const double lateral = hit.t * std::fabs(ca), depth = hit.t * std::fabs(sa);
                r = std::max(r, std::min(cap, lateral - depth * tanHalf));
            }
        }
        need[i] = r * (1.0 + options.marginFraction);
    });

    const double step = centerline.stepMm > 0 ? centerline.stepMm : 1.0;
    // Running maximum over ±window, then a Gaussian.
    const long w = long(std::lround(options.windowMm / step));
    std::vector<double> widened(n);
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t lo = i >= std::size_t(w) ? i - std::size_t(w) : 0, hi = std::min(n - 1, i + std::size_t(w));
        widened[i] = *std::max_element(need.begin() + long(lo), need.begin() + long(hi) + 1);
    }
    if (!(options.smoothMm > 0)) return widened;
    const double sigma = options.smoothMm / step;
    const long half = long(std::ceil(3 * sigma));
    std::vector<double> weights(std::size_t(2 * half + 1));
    for (long k = -half; k <= half; ++k) weights[std::size_t(k + half)] = std::exp(-0.5 * double(k * k) / (sigma * sigma));
    std::vector<double> out(n);
    for (std::size_t i = 0; i < n; ++i) {
        double sum = 0, wsum = 0;
        for (long k = -half; k <= half; ++k) {
            const long j = long(i) + k;
            if (j < 0 || j >= long(n)) continue;
            sum += weights[std::size_t(k + half)] * widened[std::size_t(j)];
            wsum += weights[std::size_t(k + half)];
        }
        out[i] = std::max(sum / wsum, centerline.points[i].radiusMm);
    }
    return out;
}

} // namespace flyover
