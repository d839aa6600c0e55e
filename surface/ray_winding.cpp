#include "surface/ray_winding.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

namespace flyover {

namespace {

using Point3d = RayWindingCounter::Vec3d;

Point3d unit(const Point3d& v) { return v / v.norm(); }

} // namespace

const std::array<Point3d, 3>& RayWindingCounter::directions()
{
    // Components of no simple ratio: no lattice row of a marching-cubes mesh runs along them.
    static const std::array<Point3d, 3> dirs{unit(Point3d(0.8017, 0.4612, 0.3803)), unit(Point3d(-0.3319, 0.8791, 0.3421)),
                                           unit(Point3d(0.2903, -0.3779, 0.8793))};
    return dirs;
}

RayWindingCounter::Triangle RayWindingCounter::triangle(std::size_t i) const
{
    if (i >= mFaces.size()) return mCaps[i - mFaces.size()];
    Triangle t;
    int k = 0;
    for (const auto v : mMesh.fv_range(mFaces[i]))
        t[std::size_t(k++)] = OpenMesh::vector_cast<Point3d>(mMesh.point(v));
    return t;
}

bool RayWindingCounter::cellOf(double s, double t, int64_t& cell) const
{
    const double fs = std::floor((s - mLoS) / mCell), ft = std::floor((t - mLoT) / mCell);
    if (!(fs >= 0 && ft >= 0 && fs < double(mNs) && ft < double(mNt))) return false;
    cell = int64_t(ft) * mNs + int64_t(fs);
    return true;
}

RayWindingCounter::RayWindingCounter(const TriMesh& mesh, const std::vector<TriMesh::FaceHandle>& faces,
                                     const std::vector<Triangle>& caps, const Point3d& direction)
    : mMesh(mesh), mFaces(faces), mCaps(caps)
{
    mDir = unit(direction);
    // Two axes across the ray.
    const Point3d helper = std::fabs(mDir[0]) < 0.9 ? Point3d(1, 0, 0) : Point3d(0, 1, 0);
    mE1 = unit(OpenMesh::cross(mDir, helper));
    mE2 = OpenMesh::cross(mDir, mE1);

    const std::size_t n = faces.size() + caps.size();
    if (n >= std::size_t(std::numeric_limits<uint32_t>::max()))
        throw std::length_error("RayWindingCounter: more than 2^32 triangles");
    // Bounds across the ray (s, t) and the surface's size (for the tolerance).
    double loS = std::numeric_limits<double>::max(), loT = loS, hiS = -loS, hiT = -loS, loH = loS, hiH = -loS;
    for (std::size_t i = 0; i < n; ++i)
        for (const Point3d& p : triangle(i)) {
            const Point3d q = project(p);
            loS = std::min(loS, q[0]), hiS = std::max(hiS, q[0]);
            loT = std::min(loT, q[1]), hiT = std::max(hiT, q[1]);
            loH = std::min(loH, q[2]), hiH = std::max(hiH, q[2]);
        }
    if (n == 0) loS = loT = hiS = hiT = loH = hiH = 0;
    const double size = std::max({hiS - loS, hiT - loT, hiH - loH, 1e-30});
    mTol = 1e-9 * size;
    // About two triangles per cell (each spans a few cells where they are small).
    const double area = std::max((hiS - loS) * (hiT - loT), size * size * 1e-6);
    const double cells = std::clamp(double(n) / 2.0, 1.0, double(1 << 24));
    mCell = std::sqrt(area / cells);
    mLoS = loS - 2 * mTol;
    mLoT = loT - 2 * mTol;
    mNs = std::max<int64_t>(1, int64_t(std::ceil((hiS - loS + 4 * mTol) / mCell)));
    mNt = std::max<int64_t>(1, int64_t(std::ceil((hiT - loT + 4 * mTol) / mCell)));

    // Compressed rows: count, prefix sum, fill (each triangle in every cell its (s, t) box,
    // grown by the tolerance, overlaps).
    const std::size_t nCells = std::size_t(mNs * mNt);
    auto cellRange = [&](std::size_t i, int64_t& s0, int64_t& s1, int64_t& t0, int64_t& t1) {
        double a0 = std::numeric_limits<double>::max(), b0 = a0, a1 = -a0, b1 = -a0;
        for (const Point3d& p : triangle(i)) {
            const Point3d q = project(p);
            a0 = std::min(a0, q[0]), a1 = std::max(a1, q[0]);
            b0 = std::min(b0, q[1]), b1 = std::max(b1, q[1]);
        }
        auto index = [&](double v, double lo, int64_t count) {
            return std::clamp<int64_t>(int64_t(std::floor((v - lo) / mCell)), 0, count - 1);
        };
        s0 = index(a0 - mTol, mLoS, mNs), s1 = index(a1 + mTol, mLoS, mNs);
        t0 = index(b0 - mTol, mLoT, mNt), t1 = index(b1 + mTol, mLoT, mNt);
    };
    std::unique_ptr<std::atomic<uint64_t>[]> count(new std::atomic<uint64_t>[nCells + 1]);
    for (std::size_t c = 0; c <= nCells; ++c) count[c].store(0, std::memory_order_relaxed);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
            int64_t s0, s1, t0, t1;
            cellRange(i, s0, s1, t0, t1);
            for (int64_t t = t0; t <= t1; ++t)
                for (int64_t s = s0; s <= s1; ++s) count[std::size_t(t * mNs + s)].fetch_add(1, std::memory_order_relaxed);
        }
    });
    mStart.assign(nCells + 1, 0);
    for (std::size_t c = 0; c < nCells; ++c) mStart[c + 1] = mStart[c] + count[c].load(std::memory_order_relaxed);
    for (std::size_t c = 0; c < nCells; ++c) count[c].store(mStart[c], std::memory_order_relaxed);
    mItems.assign(std::size_t(mStart[nCells]), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
            int64_t s0, s1, t0, t1;
            cellRange(i, s0, s1, t0, t1);
            for (int64_t t = t0; t <= t1; ++t)
                for (int64_t s = s0; s <= s1; ++s)
                    mItems[std::size_t(count[std::size_t(t * mNs + s)].fetch_add(1, std::memory_order_relaxed))] = uint32_t(i);
        }
    });
}

std::optional<int> RayWindingCounter::winding(const Point3d& p) const
{
    const Point3d q = project(p);
    int64_t cell;
    // The grid reaches 2 tolerances beyond every face's shadow: outside it, no crossing.
    if (!cellOf(q[0], q[1], cell)) return 0;
    int wn = 0;
    for (uint64_t k = mStart[std::size_t(cell)]; k < mStart[std::size_t(cell) + 1]; ++k) {
        const Triangle tri = triangle(mItems[std::size_t(k)]);
        std::array<Point3d, 3> a;
        for (int i = 0; i < 3; ++i) a[std::size_t(i)] = project(tri[std::size_t(i)]) - q;
        // Edge functions at the point (the origin now): twice the signed areas of (origin, a_i,
        // a_i+1); their sum is twice the face's signed area across the ray, whose sign tells
        // the face's side along the ray.
        std::array<double, 3> e{}, len{};
        for (int i = 0; i < 3; ++i) {
            const Point3d& u = a[std::size_t(i)];
            const Point3d& v = a[std::size_t((i + 1) % 3)];
            e[std::size_t(i)] = u[0] * v[1] - u[1] * v[0];
            len[std::size_t(i)] = std::hypot(v[0] - u[0], v[1] - u[1]);
        }
        const double area2 = e[0] + e[1] + e[2];
        const double longest = std::max({len[0], len[1], len[2]});
        if (std::fabs(area2) <= mTol * longest) {
            // Edge-on to the ray (or degenerate): no crossing of its own, but a point this
            // close to its shadow sits on a fold of the surface: too close to call.
            const double lo0 = std::min({a[0][0], a[1][0], a[2][0]});
            const double hi0 = std::max({a[0][0], a[1][0], a[2][0]});
            const double lo1 = std::min({a[0][1], a[1][1], a[2][1]});
            const double hi1 = std::max({a[0][1], a[1][1], a[2][1]});
            if (lo0 <= mTol && hi0 >= -mTol && lo1 <= mTol && hi1 >= -mTol) return std::nullopt;
            continue;
        }
        const double sign = area2 > 0 ? 1.0 : -1.0;
        double inside = std::numeric_limits<double>::max();
        for (int i = 0; i < 3; ++i) inside = std::min(inside, sign * e[std::size_t(i)] / len[std::size_t(i)]);
        if (inside < -mTol) continue;        // clearly outside its shadow
        if (inside <= mTol) return std::nullopt;  // on an edge or a vertex: too close to call
        // Barycentric weights of the origin: e[i] is opposite vertex (i + 2) % 3.
        const double h = (e[1] * a[0][2] + e[2] * a[1][2] + e[0] * a[2][2]) / area2;
        if (std::fabs(h) <= mTol) return std::nullopt;  // the point is on the face
        if (h > 0) wn += area2 > 0 ? 1 : -1;
    }
    return wn;
}

} // namespace flyover
