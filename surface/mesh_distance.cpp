#include "surface/mesh_distance.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <utility>
#include <vector>

namespace flyover {

namespace {

using Point3d = OpenMesh::Vec3d;
using Triangle = std::array<Point3d, 3>;

/// Squared distance from p to the closest point of triangle t: the closest point lies in
/// one of seven regions (the face, three edges, three vertices), found from the signs of
/// the barycentric-like dot products.
double squaredDistanceToTriangle(const Point3d& p, const Triangle& t)
{
    const Point3d ab = t[1] - t[0], ac = t[2] - t[0], ap = p - t[0];
    const double d1 = OpenMesh::dot(ab, ap), d2 = OpenMesh::dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) return ap.sqrnorm();  // vertex a

    const Point3d bp = p - t[1];
    const double d3 = OpenMesh::dot(ab, bp), d4 = OpenMesh::dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) return bp.sqrnorm();  // vertex b

    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {  // edge ab
        const double s = d1 / (d1 - d3);
        return (p - (t[0] + s * ab)).sqrnorm();
    }

    const Point3d cp = p - t[2];
    const double d5 = OpenMesh::dot(ab, cp), d6 = OpenMesh::dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) return cp.sqrnorm();  // vertex c

    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {  // edge ac
        const double s = d2 / (d2 - d6);
        return (p - (t[0] + s * ac)).sqrnorm();
    }

    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {  // edge bc
        const double s = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (t[1] + s * (t[2] - t[1]))).sqrnorm();
    }

    // Inside the face: the projection onto the plane.
    const double denominator = va + vb + vc;
    if (!(std::fabs(denominator) > 0)) {  // degenerate triangle: nearest of its edges' ends
        return std::min({ap.sqrnorm(), bp.sqrnorm(), cp.sqrnorm()});
    }
    const double v = vb / denominator, w = vc / denominator;
    return (p - (t[0] + v * ab + w * ac)).sqrnorm();
}

/// Triangles of a mesh binned into a uniform grid of cubic cells (each triangle in every
/// cell its bounding box overlaps), for nearest-triangle queries by growing shells of cells.
class TriangleGrid {
public:
    explicit TriangleGrid(const TriMesh& mesh)
    {
        mTriangles.reserve(mesh.n_faces());
        double edgeSum = 0;
        for (const auto f : mesh.faces()) {
            Triangle t;
            int k = 0;
            for (const auto v : mesh.fv_range(f)) t[std::size_t(k++)] = OpenMesh::vector_cast<Point3d>(mesh.point(v));
            for (const Point3d& p : t) {
                mLo.minimize(p);
                mHi.maximize(p);
            }
            edgeSum += (t[1] - t[0]).norm() + (t[2] - t[1]).norm() + (t[0] - t[2]).norm();
            mTriangles.push_back(t);
        }
        // Cells about twice the mean edge: a few triangles per cell, few cells per triangle.
        const double meanEdge = edgeSum / (3.0 * double(std::max<std::size_t>(1, mTriangles.size())));
        const Point3d extent = mHi - mLo;
        mCell = std::max(2.0 * meanEdge, 1e-9 * std::max({extent[0], extent[1], extent[2], 1.0}));
        // Keep the cell count bounded (a few large triangles spread far apart).
        while (cellCountFor(mCell) > 64.0 * double(mTriangles.size()) + 1e6) mCell *= 1.5;
        for (int a = 0; a < 3; ++a) mDims[a] = int64_t(std::floor(extent[a] / mCell)) + 1;

        for (std::size_t i = 0; i < mTriangles.size(); ++i) {
            const Triangle& t = mTriangles[i];
            Point3d lo = t[0], hi = t[0];
            for (const Point3d& p : t) {
                lo.minimize(p);
                hi.maximize(p);
            }
            const std::array<int64_t, 3> a = cellOf(lo), b = cellOf(hi);
            for (int64_t z = a[2]; z <= b[2]; ++z)
                for (int64_t y = a[1]; y <= b[1]; ++y)
                    for (int64_t x = a[0]; x <= b[0]; ++x) mEntries.emplace_back(key({x, y, z}), uint32_t(i));
        }
        tbb::parallel_sort(mEntries.begin(), mEntries.end());

        // Open-addressing hash from cell key to its run [begin, end) in mEntries.
        std::size_t runs = 0;
        for (std::size_t i = 0; i < mEntries.size(); ++i) runs += (i == 0 || mEntries[i].first != mEntries[i - 1].first);
        std::size_t capacity = 16;
        while (capacity < 2 * runs) capacity *= 2;
        mSlots.assign(capacity, Slot{});
        for (std::size_t i = 0; i < mEntries.size();) {
            std::size_t j = i;
            while (j < mEntries.size() && mEntries[j].first == mEntries[i].first) ++j;
            std::size_t h = hashSlot(mEntries[i].first);
            while (mSlots[h].end != 0) h = (h + 1) & (mSlots.size() - 1);
            mSlots[h] = Slot{mEntries[i].first, uint32_t(i), uint32_t(j)};
            i = j;
        }
    }

    bool empty() const { return mTriangles.empty(); }

    /// Distance (mm) from p to the nearest triangle.
    double distance(const Point3d& p) const
    {
        const std::array<int64_t, 3> c = cellOf(p);  // clamped into the grid
        const int64_t maxRing = std::max({mDims[0], mDims[1], mDims[2]});
        double best2 = std::numeric_limits<double>::max();
        for (int64_t r = 0; r <= maxRing; ++r) {
            visitShell(c, r, [&](uint64_t cellKey) {
                std::size_t h = hashSlot(cellKey);
                for (; mSlots[h].end != 0; h = (h + 1) & (mSlots.size() - 1)) {
                    if (mSlots[h].key != cellKey) continue;
                    for (uint32_t k = mSlots[h].begin; k != mSlots[h].end; ++k)
                        best2 = std::min(best2, squaredDistanceToTriangle(p, mTriangles[mEntries[k].second]));
                    break;
                }
            });
            // Every triangle not yet seen lies outside the box of cells within ring r, so at
            // least as far as that box's nearest face from p. For p outside the grid the box
            // is around its clamped cell: projecting p onto the grid's box first never brings
            // it closer to a point inside, so the bound still holds.
            double reach = std::numeric_limits<double>::max();
            for (int a = 0; a < 3; ++a) {
                const double q = std::clamp(p[a], mLo[a], mLo[a] + double(mDims[a]) * mCell);
                const double lo = mLo[a] + double(c[std::size_t(a)] - r) * mCell;
                const double hi = mLo[a] + double(c[std::size_t(a)] + r + 1) * mCell;
                if (c[std::size_t(a)] - r > 0) reach = std::min(reach, q - lo);
                if (c[std::size_t(a)] + r + 1 < mDims[a]) reach = std::min(reach, hi - q);
            }
            if (best2 <= reach * reach) break;
        }
        return std::sqrt(best2);
    }

private:
    struct Slot {
        uint64_t key = 0;
        uint32_t begin = 0, end = 0;  ///< end == 0: empty slot (a run is never empty)
    };

    std::size_t hashSlot(uint64_t key) const
    {
        key ^= key >> 33;
        key *= 0xff51afd7ed558ccdull;
        key ^= key >> 33;
        return std::size_t(key) & (mSlots.size() - 1);
    }

    double cellCountFor(double cell) const
    {
        double n = 1;
        for (int a = 0; a < 3; ++a) n *= std::floor((mHi[a] - mLo[a]) / cell) + 1;
        return n;
    }

    std::array<int64_t, 3> cellOf(const Point3d& p) const
    {
        std::array<int64_t, 3> c;
        for (int a = 0; a < 3; ++a) {
            const double x = std::floor((p[a] - mLo[a]) / mCell);
            c[std::size_t(a)] = int64_t(std::clamp(x, 0.0, double(mDims[a] - 1)));
        }
        return c;
    }

    uint64_t key(const std::array<int64_t, 3>& c) const
    {
        return uint64_t(c[0] + mDims[0] * (c[1] + mDims[1] * c[2]));
    }

    /// Calls f(key) for every in-grid cell at Chebyshev distance exactly r from c.
    template <typename F>
    void visitShell(const std::array<int64_t, 3>& c, int64_t r, const F& f) const
    {
        const int64_t z0 = std::max<int64_t>(0, c[2] - r), z1 = std::min(mDims[2] - 1, c[2] + r);
        const int64_t y0 = std::max<int64_t>(0, c[1] - r), y1 = std::min(mDims[1] - 1, c[1] + r);
        const int64_t x0 = std::max<int64_t>(0, c[0] - r), x1 = std::min(mDims[0] - 1, c[0] + r);
        for (int64_t z = z0; z <= z1; ++z)
            for (int64_t y = y0; y <= y1; ++y) {
                const bool faceRow = std::abs(z - c[2]) == r || std::abs(y - c[1]) == r;
                if (faceRow) {
                    for (int64_t x = x0; x <= x1; ++x) f(key({x, y, z}));
                } else {  // only the two ends of the row are on the shell
                    if (c[0] - r >= 0) f(key({c[0] - r, y, z}));
                    if (r > 0 && c[0] + r < mDims[0]) f(key({c[0] + r, y, z}));
                }
            }
    }

    std::vector<Triangle> mTriangles;
    std::vector<std::pair<uint64_t, uint32_t>> mEntries;  ///< (cell key, triangle), sorted
    std::vector<Slot> mSlots;
    Point3d mLo{std::numeric_limits<double>::max()}, mHi{-std::numeric_limits<double>::max()};
    double mCell = 1;
    int64_t mDims[3] = {1, 1, 1};
};

struct DistanceSum {
    double max = 0, sum = 0;
    int64_t count = 0;
    void add(double d)
    {
        max = std::max(max, d);
        sum += d;
        ++count;
    }
    static DistanceSum join(DistanceSum a, const DistanceSum& b)
    {
        a.max = std::max(a.max, b.max);
        a.sum += b.sum;
        a.count += b.count;
        return a;
    }
};

} // namespace

SurfaceDistance surfaceDistance(const TriMesh& from, const TriMesh& to, double sampleSpacingMm)
{
    if (!(sampleSpacingMm > 0)) {
        std::ostringstream msg;
        msg << "surfaceDistance: sampleSpacingMm must be > 0, got " << sampleSpacingMm;
        throw ParameterError(msg.str());
    }
    if (to.n_faces() == 0) throw ParameterError("surfaceDistance: the target mesh has no faces");
    const TriangleGrid grid(to);

    const DistanceSum vertices = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, from.n_vertices(), 1024), DistanceSum{},
        [&](const tbb::blocked_range<std::size_t>& r, DistanceSum acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i)
                acc.add(grid.distance(OpenMesh::vector_cast<Point3d>(from.point(TriMesh::VertexHandle(int(i))))));
            return acc;
        },
        DistanceSum::join);
    const DistanceSum faces = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, from.n_faces(), 256), DistanceSum{},
        [&](const tbb::blocked_range<std::size_t>& r, DistanceSum acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                Triangle t;
                int k = 0;
                for (const auto v : from.fv_range(TriMesh::FaceHandle(int(i))))
                    t[std::size_t(k++)] = OpenMesh::vector_cast<Point3d>(from.point(v));
                const double longest =
                    std::sqrt(std::max({(t[1] - t[0]).sqrnorm(), (t[2] - t[1]).sqrnorm(), (t[0] - t[2]).sqrnorm()}));
                const int n = std::max(1, int(std::ceil(longest / sampleSpacingMm)));
                const Point3d u = (t[1] - t[0]) / double(n), v = (t[2] - t[0]) / double(n);
                // Centroids of the n^2 sub-triangles: "up" ones at (i + 1/3, j + 1/3), "down"
                // ones at (i + 2/3, j + 2/3) in units of u and v.
                for (int a = 0; a < n; ++a)
                    for (int b = 0; a + b < n; ++b) {
                        acc.add(grid.distance(t[0] + (a + 1.0 / 3.0) * u + (b + 1.0 / 3.0) * v));
                        if (a + b + 1 < n) acc.add(grid.distance(t[0] + (a + 2.0 / 3.0) * u + (b + 2.0 / 3.0) * v));
                    }
            }
            return acc;
        },
        DistanceSum::join);
    const DistanceSum all = DistanceSum::join(vertices, faces);
    SurfaceDistance d;
    d.maxMm = all.max;
    d.meanMm = all.count > 0 ? all.sum / double(all.count) : 0.0;
    d.samples = all.count;
    return d;
}

double hausdorffDistanceMm(const TriMesh& a, const TriMesh& b, double sampleSpacingMm)
{
    return std::max(surfaceDistance(a, b, sampleSpacingMm).maxMm, surfaceDistance(b, a, sampleSpacingMm).maxMm);
}

} // namespace flyover
