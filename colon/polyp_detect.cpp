// Polyp candidates from the shape of the lumen's level set (polyp_detect.h lists the steps).
#include "colon/polyp_detect.h"
#include "volume/vec3.h"

#include "volume/error.h"
#include "volume/seconds_since.h"

#include <openvdb/tree/LeafManager.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <deque>
#include <mutex>
#include <sstream>

namespace flyover {

namespace {

using openvdb::Coord;
using openvdb::FloatGrid;

/// The quadric fit's stencil: offsets -2..2 on each axis, Gaussian weights of this sigma (voxels).
constexpr int FIT_RADIUS = 2;
constexpr int FIT_SIDE = 2 * FIT_RADIUS + 1;
constexpr int FIT_POINTS = FIT_SIDE * FIT_SIDE * FIT_SIDE;
constexpr double FIT_SIGMA_VOXELS = 1.25;
constexpr int FIT_TERMS = 10;  // 1, x, y, z, x^2, y^2, z^2, xy, xz, yz

/// The footprint of a candidate: the wall round its cap this far or more above the plane of
/// the surrounding wall (mm).
constexpr double FOOTPRINT_MM = 0.5;
/// Each step of the footprint's walk goes down at least this much (mm).
constexpr double FOOTPRINT_DESCENT_MM = 0.1;

/// A cap whose top goes on this far beyond its rim as a ridge is a fold's end.
constexpr double RIDGE_REACH_MM = 4.0;
/// The crest of a fold is a ridge (shape index 0.75); a valley between a cap and a fold is not.
constexpr double RIDGE_SHAPE_INDEX = 0.6;
/// ... and leaves it at least this fraction of its size wide (a fold under a polyp is narrower).
constexpr double RIDGE_WIDTH_FRACTION = 0.4;

/// The fit as a linear filter: coefficients = M * values, M = (B^T W B)^-1 B^T W.
struct QuadricFilter {
    std::array<std::array<double, FIT_POINTS>, FIT_TERMS> m{};

    QuadricFilter()
    {
        std::array<std::array<double, FIT_TERMS>, FIT_POINTS> b{};
        std::array<double, FIT_POINTS> w{};
        int k = 0;
        for (int x = -FIT_RADIUS; x <= FIT_RADIUS; ++x)
            for (int y = -FIT_RADIUS; y <= FIT_RADIUS; ++y)
                for (int z = -FIT_RADIUS; z <= FIT_RADIUS; ++z, ++k) {
                    b[k] = {1.0, double(x), double(y), double(z), double(x * x), double(y * y), double(z * z),
                            double(x * y), double(x * z), double(y * z)};
                    w[k] = std::exp(-double(x * x + y * y + z * z) / (2 * FIT_SIGMA_VOXELS * FIT_SIGMA_VOXELS));
                }
        // Normal equations [A | B^T W], solved by Gauss-Jordan elimination with partial pivoting.
        std::array<std::array<double, FIT_TERMS + FIT_POINTS>, FIT_TERMS> aug{};
        for (int r = 0; r < FIT_TERMS; ++r) {
            for (int c = 0; c < FIT_TERMS; ++c)
                for (int p = 0; p < FIT_POINTS; ++p) aug[r][c] += b[p][r] * w[p] * b[p][c];
            for (int p = 0; p < FIT_POINTS; ++p) aug[r][FIT_TERMS + p] = b[p][r] * w[p];
        }
        for (int c = 0; c < FIT_TERMS; ++c) {
            int pivot = c;
            for (int r = c + 1; r < FIT_TERMS; ++r)
                if (std::abs(aug[r][c]) > std::abs(aug[pivot][c])) pivot = r;
            std::swap(aug[c], aug[pivot]);
            const double d = aug[c][c];
            for (double& v : aug[c]) v /= d;
            for (int r = 0; r < FIT_TERMS; ++r) {
                if (r == c) continue;
                const double f = aug[r][c];
                if (f == 0) continue;
                for (int j = 0; j < FIT_TERMS + FIT_POINTS; ++j) aug[r][j] -= f * aug[c][j];
            }
        }
        for (int r = 0; r < FIT_TERMS; ++r)
            for (int p = 0; p < FIT_POINTS; ++p) m[r][p] = aug[r][FIT_TERMS + p];
    }
};

const QuadricFilter& quadricFilter()
{
    static const QuadricFilter filter;
    return filter;
}

Vec3d worldOf(const FloatGrid& sdf, const Coord& ijk) { const auto w = sdf.indexToWorld(ijk); return {w[0], w[1], w[2]}; }

/// Any unit vector perpendicular to the unit vector n.
Vec3d perpendicular(const Vec3d& n)
{
    const Vec3d a = std::abs(n.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
    return normalize(cross(n, a));
}

/// Eigen-decomposition of a symmetric 3x3 matrix by Jacobi rotations: eigenvalues ascending,
/// eigenvectors as columns in the same order.
void symmetricEigen(std::array<std::array<double, 3>, 3> a, std::array<double, 3>& values, std::array<Vec3d, 3>& vectors)
{
    std::array<std::array<double, 3>, 3> v{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
    for (int sweep = 0; sweep < 30; ++sweep) {
        const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        if (off < 1e-24) break;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                if (std::abs(a[p][q]) < 1e-300) continue;
                const double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
                const double t = (theta >= 0 ? 1.0 : -1.0) / (std::abs(theta) + std::sqrt(theta * theta + 1));
                const double c = 1 / std::sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < 3; ++k) {
                    const double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; ++k) {
                    const double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 3; ++k) {
                    const double vkp = v[k][p], vkq = v[k][q];
                    v[k][p] = c * vkp - s * vkq;
                    v[k][q] = s * vkp + c * vkq;
                }
            }
    }
    std::array<int, 3> order{0, 1, 2};
    std::sort(order.begin(), order.end(), [&](int i, int j) { return a[i][i] < a[j][j]; });
    for (int k = 0; k < 3; ++k) {
        values[k] = a[order[k]][order[k]];
        vectors[k] = {v[0][order[k]], v[1][order[k]], v[2][order[k]]};
    }
}

/// Mean and covariance of points.
struct PointSpread {
    Vec3d mean;
    std::array<double, 3> values{};
    std::array<Vec3d, 3> axes{};  ///< ascending spread
};

PointSpread spreadOf(const std::vector<Vec3d>& pts)
{
    PointSpread s;
    if (pts.empty()) return s;
    for (const Vec3d& p : pts) s.mean += p;
    s.mean = s.mean / double(pts.size());
    std::array<std::array<double, 3>, 3> c{};
    for (const Vec3d& p : pts) {
        const Vec3d d = p - s.mean;
        const double e[3] = {d.x, d.y, d.z};
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) c[i][j] += e[i] * e[j] / double(pts.size());
    }
    symmetricEigen(c, s.values, s.axes);
    return s;
}

// Step 1: the voxels within half a voxel of the wall (about one voxel per voxel face of wall).
std::vector<Coord> surfaceVoxels(const FloatGrid& sdf)
{
    const float half = float(0.5 * sdf.voxelSize()[0]);
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(sdf.tree());
    std::vector<std::vector<Coord>> perLeaf(leaves.leafCount());
    leaves.foreach([&](const openvdb::FloatTree::LeafNodeType& leaf, std::size_t n) {
        for (auto it = leaf.cbeginValueOn(); it; ++it)
            if (std::abs(*it) <= half) perLeaf[n].push_back(it.getCoord());
    });
    std::vector<Coord> out;
    for (const auto& v : perLeaf) out.insert(out.end(), v.begin(), v.end());
    return out;
}

/// Step 2 with a given accessor.
template <typename Accessor> WallShape wallShapeWith(const Accessor& acc, const FloatGrid& sdf, const Coord& ijk)
{
    const QuadricFilter& f = quadricFilter();
    std::array<double, FIT_POINTS> values{};
    int k = 0;
    for (int x = -FIT_RADIUS; x <= FIT_RADIUS; ++x)
        for (int y = -FIT_RADIUS; y <= FIT_RADIUS; ++y)
            for (int z = -FIT_RADIUS; z <= FIT_RADIUS; ++z, ++k)
                values[k] = double(acc.getValue(ijk.offsetBy(x, y, z)));
    std::array<double, FIT_TERMS> t{};
    for (int r = 0; r < FIT_TERMS; ++r) {
        double s = 0;
        for (int p = 0; p < FIT_POINTS; ++p) s += f.m[r][p] * values[p];
        t[r] = s;
    }
    // Index axes of the level set are world axes up to its linear map: map gradient and
    // Hessian through it (a scaled, possibly rotated, cubic grid).
    const openvdb::math::Mat3d inv = sdf.transform().baseMap()->getAffineMap()->getMat4().getMat3().inverse();
    const openvdb::Vec3d gIndex(t[1], t[2], t[3]);
    const openvdb::math::Mat3d hIndex(2 * t[4], t[7], t[8], t[7], 2 * t[5], t[9], t[8], t[9], 2 * t[6]);
    // world = index * M (row vectors in OpenVDB): d/dworld = inv * d/dindex.
    const openvdb::Vec3d gw = inv * gIndex;
    const openvdb::math::Mat3d hw = inv * hIndex * inv.transpose();
    WallShape s;
    const double gl = gw.length();
    const Vec3d centre = worldOf(sdf, ijk);
    if (!(gl > 1e-9)) {
        s.pointMm = centre;
        s.shapeIndex = 0.5;
        return s;
    }
    const Vec3d n{gw[0] / gl, gw[1] / gl, gw[2] / gl};  // towards the tissue (phi grows)
    s.normal = n * -1.0;
    s.pointMm = centre - n * (t[0] / gl);
    const Vec3d t1 = perpendicular(n), t2 = cross(n, t1);
    auto form = [&](const Vec3d& a, const Vec3d& b) {
        const openvdb::Vec3d bv(b.x, b.y, b.z);
        const openvdb::Vec3d hb = hw * bv;
        return -(a.x * hb[0] + a.y * hb[1] + a.z * hb[2]) / gl;
    };
    const double s11 = form(t1, t1), s22 = form(t2, t2), s12 = form(t1, t2);
    const double mean = 0.5 * (s11 + s22);
    const double dev = std::sqrt(0.25 * (s11 - s22) * (s11 - s22) + s12 * s12);
    const double c1 = mean + dev, c2 = mean - dev;
    s.shapeIndex = shapeIndexOf(c1, c2);
    s.curvednessPerMm = std::sqrt(0.5 * (c1 * c1 + c2 * c2));
    return s;
}

/// Surface voxels by index: their number in the list, or -1.
class SurfaceIndex {
public:
    explicit SurfaceIndex(const std::vector<Coord>& coords) : mGrid(openvdb::Int32Grid::create(-1))
    {
        auto acc = mGrid->getAccessor();
        for (std::size_t i = 0; i < coords.size(); ++i) acc.setValue(coords[i], int32_t(i));
    }
    openvdb::Int32Grid::ConstAccessor accessor() const { return mGrid->getConstAccessor(); }

private:
    openvdb::Int32Grid::Ptr mGrid;
};

template <typename F> void forNeighbours(const Coord& c, F&& f)
{
    for (int x = -1; x <= 1; ++x)
        for (int y = -1; y <= 1; ++y)
            for (int z = -1; z <= 1; ++z)
                if (x || y || z) f(c.offsetBy(x, y, z));
}

// Step 3: seeds grow over cap-like neighbours; one region per connected set holding a seed.
std::vector<std::vector<std::size_t>> growRegions(const std::vector<Coord>& coords, const std::vector<WallShape>& shape,
                                                  const SurfaceIndex& index, const PolypParams& p,
                                                  std::size_t& seedCount)
{
    auto isSeed = [&](std::size_t i) {
        return shape[i].shapeIndex >= p.shapeIndexSeed && shape[i].curvednessPerMm >= p.curvednessMinPerMm &&
               shape[i].curvednessPerMm <= p.curvednessMaxPerMm;
    };
    auto grows = [&](std::size_t i) {
        return shape[i].shapeIndex >= p.shapeIndexGrow && shape[i].curvednessPerMm >= 0.5 * p.curvednessMinPerMm &&
               shape[i].curvednessPerMm <= p.curvednessMaxPerMm;
    };
    std::vector<int32_t> region(coords.size(), -1);
    std::vector<std::vector<std::size_t>> regions;
    auto acc = index.accessor();
    seedCount = 0;
    for (std::size_t s = 0; s < coords.size(); ++s) {
        if (!isSeed(s)) continue;
        ++seedCount;
        if (region[s] >= 0) continue;
        const auto id = int32_t(regions.size());
        regions.emplace_back();
        std::deque<std::size_t> queue{s};
        region[s] = id;
        while (!queue.empty()) {
            const std::size_t i = queue.front();
            queue.pop_front();
            regions.back().push_back(i);
            forNeighbours(coords[i], [&](const Coord& c) {
                const int32_t j = acc.getValue(c);
                if (j < 0 || region[std::size_t(j)] >= 0 || !grows(std::size_t(j))) return;
                region[std::size_t(j)] = id;
                queue.push_back(std::size_t(j));
            });
        }
    }
    return regions;
}

/// Largest distance between two points (every pair; a stride over large sets).
double diameterOf(const std::vector<Vec3d>& pts)
{
    const std::size_t stride = std::max<std::size_t>(1, pts.size() / 1500);
    double best = 0;
    for (std::size_t i = 0; i < pts.size(); i += stride)
        for (std::size_t j = i + stride; j < pts.size(); j += stride) best = std::max(best, distance(pts[i], pts[j]));
    return best;
}

/// The plane of the wall round a candidate (n into the lumen).
struct WallModel {
    Vec3d origin, n;
    /// Height of a point above the wall, along n (mm).
    double above(const Vec3d& p) const { return dot(p - origin, n); }
};

/// The plane of the points round a candidate (their least spread), refitted twice without the
/// points more than a millimetre above the last fit (a fold beside the candidate is not the
/// wall). A plane through the candidate across `up` when there are too few points.
WallModel fitWall(std::vector<Vec3d> wall, const Vec3d& up, const Vec3d& centroid)
{
    WallModel m{centroid, up};
    for (int pass = 0; pass < 3 && wall.size() >= 3; ++pass) {
        const PointSpread ws = spreadOf(wall);
        m.n = ws.axes[0];
        if (dot(m.n, up) < 0) m.n = m.n * -1.0;
        if (dot(m.n, up) < 0.5) m.n = up;  // a degenerate ring
        m.origin = ws.mean;
        std::vector<Vec3d> low;
        for (const Vec3d& p : wall)
            if (m.above(p) <= 1.0) low.push_back(p);
        if (low.size() < 8 || low.size() == wall.size()) break;
        wall = std::move(low);
    }
    return m;
}

/// The widest crest leaving a candidate: the band points' directions round the centroid in
/// the wall's plane, in 10-degree bins; the longest run of filled bins, as an arc at their
/// mean distance (mm). A fold's end leaves as wide as its cap; a fold under a polyp narrower.
double crestWidth(const std::vector<Vec3d>& band, const Vec3d& centroid, const Vec3d& n)
{
    if (band.empty()) return 0;
    constexpr int BINS = 36;
    std::array<bool, BINS> filled{};
    const Vec3d e1 = perpendicular(n), e2 = cross(n, e1);
    double meanD = 0;
    for (const Vec3d& p : band) {
        const Vec3d d = p - centroid;
        const double angle = std::atan2(dot(d, e2), dot(d, e1));
        filled[std::size_t(std::clamp(int(std::floor((angle + PI) / (2 * PI) * BINS)), 0, BINS - 1))] = true;
        meanD += std::hypot(dot(d, e1), dot(d, e2)) / double(band.size());
    }
    int best = 0;
    for (int start = 0; start < BINS; ++start) {
        int run = 0;
        while (run < BINS && filled[std::size_t((start + run) % BINS)]) ++run;
        best = std::max(best, run);
    }
    return double(best) * (2 * PI / BINS) * meanD;
}

// Step 4: a region's measures against the plane of the wall round it.
PolypRegion measureRegion(const FloatGrid& sdf, const std::vector<Coord>& coords, const std::vector<WallShape>& shape,
                          const SurfaceIndex& index, const std::vector<std::size_t>& members)
{
    const double h = sdf.voxelSize()[0];
    PolypRegion r;
    r.voxels = members.size();
    r.areaMm2 = double(members.size()) * h * h;
    std::vector<Vec3d> pts;
    pts.reserve(members.size());
    Vec3d up;
    for (std::size_t i : members) {
        pts.push_back(shape[i].pointMm);
        up += shape[i].normal;
        r.meanShapeIndex += shape[i].shapeIndex / double(members.size());
        r.meanCurvednessPerMm += shape[i].curvednessPerMm / double(members.size());
    }
    for (const Vec3d& p : pts) r.centroidMm += p / double(pts.size());
    r.upDir = length(up) > 0 ? normalize(up) : Vec3d{0, 0, 1};
    r.sizeMm = diameterOf(pts) + h;  // wall points are voxel centres: add one voxel of extent
    auto acc = index.accessor();
    std::vector<std::size_t> sorted = members;
    std::sort(sorted.begin(), sorted.end());
    auto member = [&](int32_t j) { return j >= 0 && std::binary_search(sorted.begin(), sorted.end(), std::size_t(j)); };

    // The rim: members with a surface neighbour outside the region.
    std::vector<Vec3d> rim;
    for (std::size_t i : members) {
        bool edge = false;
        forNeighbours(coords[i], [&](const Coord& c) {
            const int32_t j = acc.getValue(c);
            if (j >= 0 && !member(j)) edge = true;
        });
        if (edge) rim.push_back(shape[i].pointMm);
    }
    // The surrounding wall: surface points in a shell 1.5 voxels to 1.5 voxels + 3 mm beyond
    // the region's radius, facing the same way (not the opposite wall, not another loop's).
    const double inner = 0.5 * r.sizeMm + 1.5 * h, outer = inner + 3.0;
    const Coord c0 = sdf.transform().worldToIndexCellCentered(openvdb::Vec3d(r.centroidMm.x, r.centroidMm.y, r.centroidMm.z));
    const int reach = int(std::ceil(outer / h)) + 1;
    std::vector<Vec3d> ring;
    for (int x = -reach; x <= reach; ++x)
        for (int y = -reach; y <= reach; ++y)
            for (int z = -reach; z <= reach; ++z) {
                const int32_t j = acc.getValue(c0.offsetBy(x, y, z));
                if (j < 0 || member(j)) continue;
                const WallShape& w = shape[std::size_t(j)];
                const double d = distance(w.pointMm, r.centroidMm);
                if (d < inner || d > outer || dot(w.normal, r.upDir) < 0.3) continue;
                ring.push_back(w.pointMm);
            }
    const WallModel wallModel = fitWall(ring.size() >= 8 ? ring : rim, r.upDir, r.centroidMm);
    const Vec3d planeNormal = wallModel.n;
    auto above = [&](const Vec3d& p) { return wallModel.above(p); };
    r.heightMm = -1e300;
    for (const Vec3d& p : pts)
        if (above(p) > r.heightMm) {
            r.heightMm = above(p);
            r.apexMm = p;
        }
    r.heightMm = std::max(0.0, r.heightMm);
    for (const Vec3d& p : rim) r.rimHeightMm += above(p) / double(rim.size());

    r.baseCentreMm = r.centroidMm - planeNormal * above(r.centroidMm);

    // The footprint: from the cap down its flanks, step by step over wall that is not concave
    // (the junction with the wall is, and so is a tube's own wall), falls (a fold's level
    // crest does not) and stays FOOTPRINT_MM or more above the surrounding wall; the size is
    // its largest diameter.
    {
        std::vector<std::size_t> queue(members.begin(), members.end());
        std::vector<std::size_t> seen = sorted;
        std::vector<Vec3d> foot = pts;
        const double limit = 0.5 * r.sizeMm + 8.0;
        for (std::size_t head = 0; head < queue.size(); ++head) {
            const double from = above(shape[queue[head]].pointMm);
            forNeighbours(coords[queue[head]], [&](const Coord& c) {
                const int32_t j = acc.getValue(c);
                if (j < 0) return;
                const auto it = std::lower_bound(seen.begin(), seen.end(), std::size_t(j));
                if (it != seen.end() && *it == std::size_t(j)) return;
                const WallShape& w = shape[std::size_t(j)];
                const double a = above(w.pointMm);
                if (a < FOOTPRINT_MM || a > from - FOOTPRINT_DESCENT_MM || w.shapeIndex < 0.5 || dot(w.normal, planeNormal) < 0.2 ||
                    distance(w.pointMm, r.centroidMm) > limit)
                    return;
                seen.insert(it, std::size_t(j));
                queue.push_back(std::size_t(j));
                foot.push_back(w.pointMm);
            });
        }
        r.sizeMm = std::max(r.sizeMm, diameterOf(foot) + h);
    }
    r.capFraction = r.areaMm2 / (PI * 0.25 * r.sizeMm * r.sizeMm);

    // Does the cap go on as a ridge? Walk from the region over convex wall (a ridge or a cap)
    // that stays between 70% and 120% of its height: a fold's round end leads along the fold's
    // crest, a polyp's cap down to the wall (a fold beside it lies beyond a concave valley).
    {
        const double level = 0.7 * r.heightMm, limit = 0.5 * r.sizeMm + 8.0;
        std::vector<Vec3d> band;  // the crest 3-5 mm beyond the footprint
        std::vector<std::size_t> queue(members.begin(), members.end());
        std::vector<std::size_t> seen = sorted;
        auto visited = [&](std::size_t j) { return std::binary_search(seen.begin(), seen.end(), j); };
        std::vector<std::size_t> fresh;
        for (std::size_t head = 0; head < queue.size(); ++head) {
            forNeighbours(coords[queue[head]], [&](const Coord& c) {
                const int32_t j = acc.getValue(c);
                if (j < 0 || visited(std::size_t(j)) ||
                    std::find(fresh.begin(), fresh.end(), std::size_t(j)) != fresh.end())
                    return;
                const WallShape& w = shape[std::size_t(j)];
                const double d = distance(w.pointMm, r.centroidMm);
                const double a = above(w.pointMm);
                if (d > limit || a < level || a > 1.2 * r.heightMm + 1.0 || w.shapeIndex < RIDGE_SHAPE_INDEX ||
                    dot(w.normal, planeNormal) < 0.2)
                    return;
                fresh.push_back(std::size_t(j));
                queue.push_back(std::size_t(j));
                r.ridgeReachMm = std::max(r.ridgeReachMm, d - 0.5 * r.sizeMm);
                if (d - 0.5 * r.sizeMm >= 3.0 && d - 0.5 * r.sizeMm <= 5.0) band.push_back(w.pointMm);
            });
            if (fresh.size() > 256) {
                seen.insert(seen.end(), fresh.begin(), fresh.end());
                std::sort(seen.begin(), seen.end());
                fresh.clear();
            }
        }
        r.crestWidthMm = crestWidth(band, r.centroidMm, planeNormal);
    }

    // Elongation: the spread of the region's points along the wall's plane.
    std::vector<Vec3d> flat;
    flat.reserve(pts.size());
    for (const Vec3d& p : pts) flat.push_back(p - planeNormal * above(p));
    const PointSpread fs = spreadOf(flat);
    r.elongation = std::sqrt(std::max(fs.values[2], 1e-12) / std::max(fs.values[1], 1e-6 * h * h));

    r.planeNormal = planeNormal;
    r.volumeMm3 = double(polypBodyVoxels(sdf, r).size()) * h * h * h;

    if (r.heightMm < 3.0 && r.heightMm < 0.4 * r.sizeMm) r.morphology = "flat";
    else if (r.rimHeightMm >= 0.4 * r.heightMm && r.heightMm >= 0.6 * r.sizeMm) r.morphology = "pedunculated";
    else r.morphology = "sessile";
    return r;
}

double clamp01(double v) { return std::clamp(v, 0.0, 1.0); }

// Step 5: the rules, and the score of what passes them.
void judgeRegion(PolypRegion& r, const PolypParams& p)
{
    if (r.sizeMm < p.minSizeMm) r.dropped = "smaller than polyps.min_size_mm";
    else if (r.heightMm < p.minHeightMm) r.dropped = "lower than polyps.min_height_mm";
    else if (r.elongation > p.maxElongation) r.dropped = "elongated (a fold; polyps.max_elongation)";
    else if (r.ridgeReachMm >= RIDGE_REACH_MM && r.crestWidthMm >= RIDGE_WIDTH_FRACTION * r.sizeMm)
        r.dropped = "goes on as a ridge (a fold's end)";
    else if (r.capFraction < p.minCapFraction) r.dropped = "a small cap on a broad swelling (polyps.min_cap_fraction)";
    const double si = clamp01((r.meanShapeIndex - p.shapeIndexGrow) / (1.0 - p.shapeIndexGrow));
    const double round = clamp01((p.maxElongation - r.elongation) / (p.maxElongation - 1.0));
    const double rise = clamp01(r.heightMm / (0.5 * std::max(r.sizeMm, 1e-9)));
    const double size = clamp01((r.sizeMm - p.minSizeMm) / std::max(10.0 - p.minSizeMm, 1.0));
    r.score = 0.3 * si + 0.2 * round + 0.3 * rise + 0.2 * size;
}

} // namespace

std::vector<openvdb::Coord> polypBodyVoxels(const openvdb::FloatGrid& sdf, const PolypRegion& r)
{
    const double h = sdf.voxelSize()[0];
    const double ball = 0.5 * r.sizeMm + h;
    const Coord b0 = sdf.transform().worldToIndexCellCentered(openvdb::Vec3d(r.baseCentreMm.x, r.baseCentreMm.y, r.baseCentreMm.z));
    const int reach = int(std::ceil(ball / h));
    auto acc = sdf.getConstAccessor();
    std::vector<Coord> out;
    for (int x = -reach; x <= reach; ++x)
        for (int y = -reach; y <= reach; ++y)
            for (int z = -reach; z <= reach; ++z) {
                const Coord c = b0.offsetBy(x, y, z);
                const Vec3d w = worldOf(sdf, c);
                if (distance(w, r.baseCentreMm) > ball || dot(w - r.baseCentreMm, r.planeNormal) <= 0 ||
                    !(acc.getValue(c) > 0))
                    continue;
                out.push_back(c);
            }
    return out;
}

double shapeIndexOf(double c1, double c2)
{
    if (c1 < c2) std::swap(c1, c2);
    if (c1 == 0 && c2 == 0) return 0.5;
    return 0.5 + std::atan2(c1 + c2, c1 - c2) / PI;
}

WallShape wallShapeAt(const openvdb::FloatGrid& sdf, const openvdb::Coord& ijk)
{
    return wallShapeWith(sdf.getConstAccessor(), sdf, ijk);
}

void validatePolypParams(const PolypParams& p)
{
    auto require = [](bool ok, const char* name, const char* what) {
        if (!ok) throw ParameterError(std::string("polyps.") + name + ": " + what);
    };
    require(p.shapeIndexSeed > 0.5 && p.shapeIndexSeed <= 1, "shape_index_seed", "must be in (0.5, 1]");
    require(p.shapeIndexGrow > 0.5 && p.shapeIndexGrow <= p.shapeIndexSeed, "shape_index_grow",
            "must be in (0.5, polyps.shape_index_seed]");
    require(p.curvednessMinPerMm > 0 && p.curvednessMinPerMm < p.curvednessMaxPerMm, "curvedness_min_per_mm",
            "must be > 0 and below polyps.curvedness_max_per_mm");
    require(p.curvednessMaxPerMm <= 10, "curvedness_max_per_mm", "must be <= 10");
    require(p.minSizeMm >= 0 && p.minSizeMm <= 100, "min_size_mm", "must be in [0, 100]");
    require(p.minHeightMm >= 0 && p.minHeightMm <= 100, "min_height_mm", "must be in [0, 100]");
    require(p.maxElongation >= 1, "max_elongation", "must be >= 1");
    require(p.minCapFraction >= 0 && p.minCapFraction <= 1, "min_cap_fraction", "must be in [0, 1]");
    require(p.maxCandidates >= 0 && p.maxCandidates <= 1000, "max_candidates", "must be in [0, 1000]");
    require(p.cropMm >= 10 && p.cropMm <= 500, "crop_mm", "must be in [10, 500]");
}

PolypDetection detectPolyps(const openvdb::FloatGrid& sdf, const PolypParams& params)
{
    validatePolypParams(params);
    const auto t0 = std::chrono::steady_clock::now();
    const openvdb::Vec3d vs = sdf.voxelSize();
    if (std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] || std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
        throw InputError("polyps: the lumen level set's voxels are not cubic");
    PolypDetection out;
    const std::vector<Coord> coords = surfaceVoxels(sdf);
    out.surfaceVoxels = coords.size();
    std::vector<WallShape> shape(coords.size());
    tbb::enumerable_thread_specific<FloatGrid::ConstAccessor> accessors([&] { return sdf.getConstAccessor(); });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, coords.size(), 512), [&](const auto& range) {
        auto& acc = accessors.local();
        for (std::size_t i = range.begin(); i != range.end(); ++i) shape[i] = wallShapeWith(acc, sdf, coords[i]);
    });
    const SurfaceIndex index(coords);
    const auto regions = growRegions(coords, shape, index, params, out.seedVoxels);
    out.regions = regions.size();
    std::vector<PolypRegion> measured(regions.size());
    tbb::parallel_for(std::size_t(0), regions.size(), [&](std::size_t k) {
        measured[k] = measureRegion(sdf, coords, shape, index, regions[k]);
        judgeRegion(measured[k], params);
    });
    std::sort(measured.begin(), measured.end(), [](const PolypRegion& a, const PolypRegion& b) { return a.score > b.score; });
    // One polyp split in two regions: the lower-scored of two kept regions closer than half
    // the larger's size is a duplicate.
    for (PolypRegion& r : measured) {
        if (r.dropped.empty())
            for (const PolypRegion& k : out.candidates)
                if (distance(k.centroidMm, r.centroidMm) < 0.5 * std::max(k.sizeMm, r.sizeMm)) {
                    r.dropped = "part of a better candidate";
                    break;
                }
        if (r.dropped.empty()) out.candidates.push_back(r);
        else {
            ++out.droppedBy[r.dropped];
            out.dropped.push_back(r);
        }
    }
    out.seconds = secondsSince(t0);
    return out;
}

} // namespace flyover
