#include "colon/centerline_far_end.h"

#include <algorithm>
#include <cmath>

namespace flyover {

std::optional<NarrowFarEnd> narrowFarEnd(const std::vector<Vec3d>& path,
                                         const std::function<double(const Vec3d&)>& depthMm)
{
    if (path.size() < 3) return std::nullopt;
    std::vector<double> arc(path.size(), 0.0);
    for (std::size_t i = 1; i < path.size(); ++i) arc[i] = arc[i - 1] + distance(path[i - 1], path[i]);
    const double length = arc.back();
    if (length < 100.0) return std::nullopt;
    const double window = std::max(FAR_WINDOW_MM, FAR_WINDOW_FRACTION * length);
    // Depths every ~1 mm of the far window (the samples are far closer; the depth is smooth).
    std::vector<std::size_t> at;
    for (std::size_t i = path.size(); i-- > 0;) {
        if (arc[i] < length - window) break;
        if (at.empty() || arc[at.back()] - arc[i] >= 1.0) at.push_back(i);
    }
    std::vector<double> depth(at.size());
    double wide = 0;
    for (std::size_t k = 0; k < at.size(); ++k) {
        depth[k] = depthMm(path[at[k]]);
        wide = std::max(wide, depth[k]);
    }
    if (!(wide > 0)) return std::nullopt;
    // `at` runs from the far end backwards: the mouth is the first sample as deep as the wide
    // lumen's WIDE_FRACTION.
    std::size_t k = 0;
    while (k < at.size() && depth[k] < WIDE_FRACTION * wide) ++k;
    if (k == at.size()) return std::nullopt;
    NarrowFarEnd out;
    out.mouthIndex = at[k];
    out.wideDepthMm = wide;
    out.lengthMm = length - arc[out.mouthIndex];
    if (out.lengthMm < std::max(30.0, wide)) return std::nullopt;
    // The tube's own depth, past the mouth's rim (half the wide depth on).
    const double rim = arc[out.mouthIndex] + 0.5 * wide;
    for (std::size_t j = 0; j < k; ++j)
        if (arc[at[j]] > rim) out.narrowDepthMm = std::max(out.narrowDepthMm, depth[j]);
    if (!(out.narrowDepthMm > 0)) return std::nullopt;
    // The plug: its ball (1.5 tube depths) starts past the rim and ends before the far end.
    out.plugRadiusMm = 1.5 * out.narrowDepthMm;
    const double plugArc = rim + out.plugRadiusMm;
    if (plugArc + out.plugRadiusMm > length) return std::nullopt;
    const auto it = std::lower_bound(arc.begin(), arc.end(), plugArc);
    out.plugMm = path[std::size_t(it - arc.begin())];
    return out;
}

} // namespace flyover
