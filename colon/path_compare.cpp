#include "colon/path_compare.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace flyover {

std::vector<double> arcLengthsMm(const std::vector<Vec3d>& points)
{
    std::vector<double> arc(points.size(), 0.0);
    for (std::size_t i = 1; i < points.size(); ++i) arc[i] = arc[i - 1] + distance(points[i], points[i - 1]);
    return arc;
}

PathComparison comparePathToReference(const std::vector<Vec3d>& path, const std::vector<Vec3d>& reference)
{
    if (path.empty() || reference.empty())
        throw std::invalid_argument("comparePathToReference: the path and the reference need points");
    const std::vector<double> refArc = arcLengthsMm(reference);

    PathComparison c;
    c.errorMm.reserve(path.size());
    c.referenceArcMm.reserve(path.size());
    for (const Vec3d& p : path) {
        std::size_t best = 0;
        double bestD = distance(reference[0], p);
        for (std::size_t i = 1; i < reference.size(); ++i) {
            const double d = distance(reference[i], p);
            if (d < bestD) {
                bestD = d;
                best = i;
            }
        }
        c.errorMm.push_back(bestD);
        c.referenceArcMm.push_back(refArc[best]);
    }
    std::vector<double> sorted(c.errorMm);
    std::sort(sorted.begin(), sorted.end());
    for (double e : c.errorMm) c.meanErrorMm += e / double(c.errorMm.size());
    c.p95ErrorMm = sorted[std::size_t(0.95 * double(sorted.size() - 1))];
    for (std::size_t i = 1; i < path.size(); ++i) {
        const double step = c.referenceArcMm[i] - c.referenceArcMm[i - 1];
        if (std::abs(step) > c.worstJumpMm) {
            c.worstJumpMm = std::abs(step);
            c.worstJumpAt = i;
        }
        c.worstBackwardsMm = std::max(c.worstBackwardsMm, -step);
    }
    return c;
}

} // namespace flyover
