#include "volume/centerline_types.h"

#include <cmath>

namespace flyover {

namespace {

/// Removes from `v` its component along the unit vector `t` and normalises the result; when
/// `v` is (nearly) parallel to `t`, falls back to a perpendicular built from the axis least
/// aligned with `t`.
Vec3d perpendicularPart(const Vec3d& v, const Vec3d& t)
{
    Vec3d p = v - t * dot(v, t);
    if (length(p) > 1e-9) return normalize(p);
    const Vec3d a = std::fabs(t.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
    return normalize(a - t * dot(a, t));
}

} // namespace

void computeTangentsAndNormals(Centerline& centerline)
{
    auto& pts = centerline.points;
    const std::size_t n = pts.size();
    if (n == 0) return;
    if (n == 1) {
        pts[0].tangent = {0, 0, 1};
        pts[0].normal = {1, 0, 0};
        return;
    }
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t a = i == 0 ? 0 : i - 1;
        const std::size_t b = i + 1 == n ? n - 1 : i + 1;
        pts[i].tangent = normalize(pts[b].positionMm - pts[a].positionMm);
    }

    // Thesis V.A: the first normal is (dy, -dx, 0) of the first segment, or (1, 0, 0) when the
    // segment runs along z.
    const Vec3d d = pts[1].positionMm - pts[0].positionMm;
    const double horizontal = std::hypot(d.x, d.y);
    Vec3d first = horizontal > 1e-9 * length(d) ? Vec3d{d.y, -d.x, 0} : Vec3d{1, 0, 0};
    pts[0].normal = perpendicularPart(first, pts[0].tangent);

    // Thesis V.A alignment: the previous camera point p_cam(i-1) = p(i-1) + n(i-1) is slid along
    // the local direction of travel until it lies in the plane through p(i) perpendicular to it;
    // algebraically that is n(i-1) with its component along the direction removed. We use the
    // central-difference tangent as that direction so that n(i) is exactly perpendicular to
    // t(i), which the cameras need; the result is a discrete rotation-minimising frame.
    for (std::size_t i = 1; i < n; ++i)
        pts[i].normal = perpendicularPart(pts[i - 1].normal, pts[i].tangent);
}

} // namespace flyover
