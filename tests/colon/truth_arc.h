// Shared by the phantom tests: where a point lies along the phantom's truth centerline.
#pragma once

#include "volume/vec3.h"

#include <algorithm>
#include <cstddef>
#include <vector>

namespace flyover::test {

/// Arc length (mm) of the truth centerline sample nearest to p (1 mm samples): a search
/// every 8 samples, refined around the best one (parts of the colon that are not adjacent
/// lie far further apart than 8 mm).
inline double nearestArcMm(const std::vector<Vec3d>& c, const Vec3d& p)
{
    std::size_t best = 0;
    for (std::size_t i = 0; i < c.size(); i += 8)
        if (distance(c[i], p) < distance(c[best], p)) best = i;
    const std::size_t lo = best >= 8 ? best - 8 : 0, hi = std::min(c.size() - 1, best + 8);
    for (std::size_t i = lo; i <= hi; ++i)
        if (distance(c[i], p) < distance(c[best], p)) best = i;
    return double(best);
}

} // namespace flyover::test
