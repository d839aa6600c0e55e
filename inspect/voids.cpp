/// @file voids.cpp
/// @brief Internal voids of a solid part (see voids.h). All OpenVDB tool templates used for
///        the part analysis (segmentation, morphology, counting, meshing) live in this TU.
///
/// Steps and choices:
/// 1. Grey-value histogram over the scan box B (the CT grid's active bounding box): every
///    voxel of B counts once, stored or not (leaf voxels by value whatever their active
///    state, tiles by value x voxels of B they cover, the rest of B by the background
///    value); 4096 equal bins from the smallest to the largest value. Otsu's threshold
///    maximises the between-class variance; its separability eta = between / total
///    variance must be >= 0.8 (one Gaussian phase gives 2/pi = 0.64), else the volume has
///    one phase only (no material or all material) and is refused.
/// 2. material = voxels of B >= threshold; air = B minus material.
/// 3. Air components, 6-connected (face neighbours; OpenVDB's extractActiveVoxelSegmentMasks):
///    material is then 26-connected, the digital-topology dual, so a void stays internal
///    unless a face-connected air path reaches the border: an edge or corner contact through
///    the material is a sub-voxel opening that noise makes or breaks at random, and counting
///    it as an opening would let single noisy voxels join pores to the outside. Components
///    that touch a face of B are outside air (the bore is open at both ends and touches
///    B; an open crack joins them); the others are internal voids.
/// 4. Partial volume: m = (v - A) / (M - A) is a voxel's material fraction, with A the mean
///    grey value of the outside air farther than 2 voxels (Chebyshev) from the part and M
///    the mean of the material farther than 2 voxels from any air. Blur keeps volumes and
///    noise averages out, so summing m (or a = 1 - m) over a region that holds a surface's
///    whole blur measures the volume on each side of it to a fraction of a voxel, free of
///    the curvature bias of counting thresholded voxels. Void volume = sum of a over its
///    voxels and the material voxels within 2 (Chebyshev) of it that are nearer to it than
///    to any other air (half weight on a tie). Material volume = sum of m over the part
///    dilated by 2 voxels (26-neighbours): beyond that m is 0 up to noise, and A is the mean
///    there, so nothing is lost or added.
#include "inspect/voids.h"
#include "volume/vec3.h"

#include "volume/error.h"
#include "volume/union_find.h"

#include <openvdb/tools/Count.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <openvdb/tree/LeafManager.h>
#include <openvdb/math/Mat3.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

using openvdb::BoolTree;
using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::FloatTree;
using openvdb::Index64;

namespace {

constexpr int HISTOGRAM_BINS = 4096;
constexpr double MIN_SEPARABILITY = 0.8;
constexpr int SHELL_VOXELS = 2;         // partial-volume shell and rim width (Chebyshev)
constexpr double CRACK_FLATNESS = 0.3;  // sqrt(lambda_min / lambda_mid) below this: crack
constexpr int64_t MAX_LOCAL_BOX = int64_t(1) << 27;  // voxels of one void's local box

std::string num(double v)
{
    std::ostringstream o;
    o.precision(6);
    o << v;
    return o.str();
}

/// Values of B's voxels that are not in a CT leaf: tiles (active or not) and the background.
struct TileBlock {
    CoordBBox box;   // clipped to B
    float value;
};

std::vector<TileBlock> tileBlocks(const FloatTree& tree, const CoordBBox& b, Index64& covered)
{
    std::vector<TileBlock> blocks;
    covered = 0;
    auto it = tree.cbeginValueAll();
    it.setMaxDepth(FloatTree::ValueAllCIter::LEAF_DEPTH - 1);  // tiles only, no leaf voxels
    for (; it; ++it) {
        CoordBBox tb;
        it.getBoundingBox(tb);
        tb.intersect(b);
        if (tb.empty()) continue;
        blocks.push_back({tb, *it});
        covered += tb.volume();
    }
    return blocks;
}

struct ValueStats {
    double minV = std::numeric_limits<double>::infinity(), maxV = -std::numeric_limits<double>::infinity();
    double sum = 0;
    Index64 count = 0;
    bool finite = true;
};

/// Calls f(value, count) for every voxel of B: leaf voxels one by one (in parallel chunks,
/// each with its own Acc), tiles and the background in blocks.
template <typename Acc, typename LeafFn, typename BlockFn>
Acc reduceOverBox(const FloatTree& tree, const CoordBBox& b, const LeafFn& leafFn, const BlockFn& blockFn)
{
    openvdb::tree::LeafManager<const FloatTree> leaves(tree);
    Acc total = tbb::parallel_reduce(
        leaves.leafRange(), Acc(),
        [&](const openvdb::tree::LeafManager<const FloatTree>::LeafRange& r, Acc acc) {
            for (auto leaf = r.begin(); leaf; ++leaf) {
                const CoordBBox lb = leaf->getNodeBoundingBox();
                const bool whole = b.isInside(lb);
                for (openvdb::Index off = 0; off < FloatTree::LeafNodeType::SIZE; ++off) {
                    if (!whole && !b.isInside(leaf->offsetToGlobalCoord(off))) continue;
                    leafFn(acc, static_cast<double>(leaf->getValue(off)), 1);
                }
            }
            return acc;
        },
        [](Acc a, const Acc& o) { a.merge(o); return a; });
    Index64 covered = 0;
    for (const TileBlock& t : tileBlocks(tree, b, covered)) blockFn(total, static_cast<double>(t.value), t.box.volume());
    Index64 inLeaves = 0;
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        CoordBBox lb = leaf->getNodeBoundingBox();
        lb.intersect(b);
        if (!lb.empty()) inLeaves += lb.volume();
    }
    const Index64 rest = b.volume() - covered - inLeaves;
    if (rest > 0) blockFn(total, static_cast<double>(tree.background()), rest);
    return total;
}

struct StatsAcc {
    ValueStats s;
    void add(double v, Index64 n)
    {
        if (!std::isfinite(v)) { s.finite = false; return; }
        s.minV = std::min(s.minV, v);
        s.maxV = std::max(s.maxV, v);
        s.sum += v * static_cast<double>(n);
        s.count += n;
    }
    void merge(const StatsAcc& o)
    {
        s.minV = std::min(s.minV, o.s.minV);
        s.maxV = std::max(s.maxV, o.s.maxV);
        s.sum += o.s.sum;
        s.count += o.s.count;
        s.finite = s.finite && o.s.finite;
    }
};

struct HistAcc {
    std::vector<Index64> bins;
    double lo = 0, scale = 0;
    void add(double v, Index64 n)
    {
        if (bins.empty()) bins.assign(HISTOGRAM_BINS, 0);
        const int k = std::clamp(static_cast<int>((v - lo) * scale), 0, HISTOGRAM_BINS - 1);
        bins[static_cast<std::size_t>(k)] += n;
    }
    void merge(const HistAcc& o)
    {
        if (o.bins.empty()) return;
        if (bins.empty()) { bins = o.bins; return; }
        for (std::size_t i = 0; i < bins.size(); ++i) bins[i] += o.bins[i];
    }
};

struct OtsuResult {
    double threshold = 0, separability = 0;
};

OtsuResult otsu(const std::vector<Index64>& bins, double lo, double binWidth)
{
    double total = 0, sumAll = 0, sumSqAll = 0;
    for (std::size_t i = 0; i < bins.size(); ++i) {
        const double x = lo + (i + 0.5) * binWidth, n = static_cast<double>(bins[i]);
        total += n;
        sumAll += n * x;
        sumSqAll += n * x * x;
    }
    const double mean = sumAll / total, varTotal = sumSqAll / total - mean * mean;
    double w0 = 0, sum0 = 0, best = -1;
    std::size_t bestK = 0;
    for (std::size_t k = 0; k + 1 < bins.size(); ++k) {
        const double x = lo + (k + 0.5) * binWidth;
        w0 += static_cast<double>(bins[k]);
        sum0 += static_cast<double>(bins[k]) * x;
        const double w1 = total - w0;
        if (w0 <= 0 || w1 <= 0) continue;
        const double m0 = sum0 / w0, m1 = (sumAll - sum0) / w1;
        const double between = (w0 / total) * (w1 / total) * (m1 - m0) * (m1 - m0);
        if (between > best) { best = between; bestK = k; }
    }
    OtsuResult r;
    r.threshold = lo + (bestK + 1) * binWidth;  // material: bins above bestK
    r.separability = varTotal > 0 ? std::max(0.0, best) / varTotal : 0.0;
    return r;
}

/// A BoolTree over B: active where pred(grey value) holds. Voxels of B outside every CT node
/// take the background value.
template <typename Pred>
BoolTree::Ptr maskFromGrey(const FloatTree& ct, const CoordBBox& b, const Pred& pred)
{
    BoolTree::Ptr mask(new BoolTree(false));
    // leaves: same origins as the CT's, filled in parallel
    std::vector<const FloatTree::LeafNodeType*> ctLeaves;
    ct.getNodes(ctLeaves);
    std::vector<BoolTree::LeafNodeType*> out(ctLeaves.size(), nullptr);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ctLeaves.size()), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t n = r.begin(); n < r.end(); ++n) {
            const FloatTree::LeafNodeType& src = *ctLeaves[n];
            const CoordBBox lb = src.getNodeBoundingBox();
            if (!b.hasOverlap(lb)) continue;
            const bool whole = b.isInside(lb);
            auto* leaf = new BoolTree::LeafNodeType(src.origin(), false, false);
            bool any = false;
            for (openvdb::Index off = 0; off < FloatTree::LeafNodeType::SIZE; ++off) {
                if (!whole && !b.isInside(src.offsetToGlobalCoord(off))) continue;
                if (pred(src.getValue(off))) {
                    leaf->setValueOn(off, true);
                    any = true;
                }
            }
            if (any) out[n] = leaf;
            else delete leaf;
        }
    });
    for (auto* leaf : out)
        if (leaf) mask->addLeaf(leaf);
    Index64 covered = 0;
    for (const TileBlock& t : tileBlocks(ct, b, covered))
        if (pred(t.value)) mask->fill(t.box, true, true);
    return mask;
}

struct Moments {
    Index64 n = 0;
    double sum = 0;
    void merge(const Moments& o) { n += o.n; sum += o.sum; }
};

/// Sum and count of the CT's grey values over the active voxels of `mask` (within B).
Moments greyOverMask(const FloatTree& ct, const BoolTree& mask)
{
    openvdb::tree::LeafManager<const BoolTree> leaves(mask);
    Moments m = tbb::parallel_reduce(
        leaves.leafRange(), Moments(),
        [&](const openvdb::tree::LeafManager<const BoolTree>::LeafRange& r, Moments acc) {
            openvdb::tree::ValueAccessor<const FloatTree> a(ct);
            for (auto leaf = r.begin(); leaf; ++leaf) {
                const FloatTree::LeafNodeType* src = a.probeConstLeaf(leaf->origin());
                for (auto it = leaf->cbeginValueOn(); it; ++it) {
                    acc.sum += src ? src->getValue(it.pos()) : a.getValue(it.getCoord());
                    ++acc.n;
                }
            }
            return acc;
        },
        [](Moments x, const Moments& y) { x.merge(y); return x; });
    // active tiles of the mask (leaf-aligned boxes): whole CT leaves, or the CT's tile value
    auto it = mask.cbeginValueOn();
    it.setMaxDepth(BoolTree::ValueOnCIter::LEAF_DEPTH - 1);
    const int dim = static_cast<int>(FloatTree::LeafNodeType::DIM);
    for (; it; ++it) {
        CoordBBox tb;
        it.getBoundingBox(tb);
        Moments t = tbb::parallel_reduce(
            tbb::blocked_range<int>(0, (tb.max().z() - tb.min().z()) / dim + 1), Moments(),
            [&](const tbb::blocked_range<int>& r, Moments acc) {
                openvdb::tree::ValueAccessor<const FloatTree> a(ct);
                for (int zi = r.begin(); zi < r.end(); ++zi)
                    for (int y = tb.min().y(); y <= tb.max().y(); y += dim)
                        for (int x = tb.min().x(); x <= tb.max().x(); x += dim) {
                            const Coord o(x, y, tb.min().z() + zi * dim);
                            if (const FloatTree::LeafNodeType* leaf = a.probeConstLeaf(o)) {
                                for (openvdb::Index off = 0; off < FloatTree::LeafNodeType::SIZE; ++off)
                                    acc.sum += leaf->getValue(off);
                            } else {
                                acc.sum += static_cast<double>(a.getValue(o)) * FloatTree::LeafNodeType::SIZE;
                            }
                            acc.n += FloatTree::LeafNodeType::SIZE;
                        }
                return acc;
            },
            [](Moments x, const Moments& y) { x.merge(y); return x; });
        m.merge(t);
    }
    return m;
}

/// Distance (voxels) from p (index space) to the nearest active voxel centre of `tree`:
/// best-first over the tree's nodes, nearest bounding box first, pruned by the best so far.
class NearestActive {
public:
    using RootT = BoolTree::RootNodeType;
    explicit NearestActive(const BoolTree& tree) : mTree(tree) {}

    double distance(const openvdb::Vec3d& p)
    {
        mP = p;
        mBest2 = std::numeric_limits<double>::infinity();
        const RootT& root = mTree.root();
        for (auto it = root.cbeginValueOn(); it; ++it)
            tile(CoordBBox::createCube(it.getCoord(), RootT::ChildNodeType::DIM));
        std::vector<std::pair<double, const RootT::ChildNodeType*>> kids;
        for (auto it = root.cbeginChildOn(); it; ++it) kids.emplace_back(boxD2(it->getNodeBoundingBox()), &*it);
        std::sort(kids.begin(), kids.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
        for (const auto& k : kids) {
            if (k.first >= mBest2) break;
            visit(*k.second);
        }
        return std::sqrt(mBest2);
    }

private:
    double boxD2(const CoordBBox& b) const
    {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
            const double lo = b.min()[a], hi = b.max()[a], v = mP[a];
            const double d = v < lo ? lo - v : (v > hi ? v - hi : 0.0);
            d2 += d * d;
        }
        return d2;
    }
    void tile(const CoordBBox& b)
    {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
            const double q = std::clamp(std::round(mP[a]), double(b.min()[a]), double(b.max()[a]));
            d2 += (q - mP[a]) * (q - mP[a]);
        }
        mBest2 = std::min(mBest2, d2);
    }
    template <typename NodeT>
    void visit(const NodeT& node)
    {
        if (boxD2(node.getNodeBoundingBox()) >= mBest2) return;
        if constexpr (NodeT::LEVEL == 0) {
            for (auto it = node.cbeginValueOn(); it; ++it) {
                const Coord c = it.getCoord();
                const double dx = c.x() - mP[0], dy = c.y() - mP[1], dz = c.z() - mP[2];
                mBest2 = std::min(mBest2, dx * dx + dy * dy + dz * dz);
            }
        } else {
            for (auto it = node.cbeginValueOn(); it; ++it)
                tile(CoordBBox::createCube(it.getCoord(), NodeT::ChildNodeType::DIM));
            std::vector<std::pair<double, const typename NodeT::ChildNodeType*>> kids;
            for (auto it = node.cbeginChildOn(); it; ++it) kids.emplace_back(boxD2(it->getNodeBoundingBox()), &*it);
            std::sort(kids.begin(), kids.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
            for (const auto& k : kids) {
                if (k.first >= mBest2) break;
                visit(*k.second);
            }
        }
    }

    const BoolTree& mTree;
    openvdb::Vec3d mP;
    double mBest2 = 0;
};

/// One internal void while it is measured.
struct VoidWork {
    BoolTree::Ptr mask;
    Index64 voxels = 0;
    CoordBBox bbox;
    double volumeVoxels = 0;        // partial volume (voxels)
    double areaVoxels = 0;          // iso-surface area (voxel units^2)
    double isoVolumeVoxels = 0;     // volume enclosed by that iso-surface (voxel units^3)
    double extentVoxels = 0;
    openvdb::Vec3d centroid;        // index space
    double flatness = 1;            // sqrt(lambda_min / lambda_mid)
    bool measuredByPartialVolume = true;
};

/// Local dense box around one void: partial volume, surface area, extent, shape.
void measureVoid(VoidWork& w, const FloatTree& ct, const BoolTree& air, double airGrey, double materialGrey,
                 bool listed)
{
    // voxel statistics
    openvdb::Vec3d sum(0.0);
    for (auto it = w.mask->cbeginValueOn(); it; ++it) sum += it.getCoord().asVec3d();
    w.centroid = sum / static_cast<double>(w.voxels);
    openvdb::math::Mat3d cov(openvdb::math::Mat3d::zero());
    for (auto it = w.mask->cbeginValueOn(); it; ++it) {
        const openvdb::Vec3d d = it.getCoord().asVec3d() - w.centroid;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) cov(r, c) += d[r] * d[c];
    }
    cov *= 1.0 / static_cast<double>(w.voxels);
    for (int a = 0; a < 3; ++a) cov(a, a) += 1.0 / 12.0;  // each voxel a unit cube, not a point
    openvdb::math::Mat3d q;
    openvdb::Vec3d eig;
    openvdb::math::diagonalizeSymmetricMatrix(cov, q, eig);
    std::array<double, 3> l = {eig[0], eig[1], eig[2]};
    std::sort(l.begin(), l.end());
    w.flatness = l[1] > 0 ? std::sqrt(std::max(0.0, l[0]) / l[1]) : 1.0;

    const int pad = SHELL_VOXELS + 1;
    const Coord lo = w.bbox.min() - Coord(pad), hi = w.bbox.max() + Coord(pad);
    const Coord dim = hi - lo + Coord(1);
    const int64_t nx = dim.x(), ny = dim.y(), nz = dim.z();
    if (nx * ny * nz > MAX_LOCAL_BOX) {
        // huge void: voxel count, no shell, no mesh (documented in the README)
        w.measuredByPartialVolume = false;
        w.volumeVoxels = static_cast<double>(w.voxels);
        std::vector<openvdb::Vec3d> none;
        w.extentVoxels = std::max(0.0, std::sqrt(12.0 * l[2]));
        return;
    }
    auto at = [&](int64_t x, int64_t y, int64_t z) { return static_cast<std::size_t>((z * ny + y) * nx + x); };
    const std::size_t total = static_cast<std::size_t>(nx * ny * nz);
    std::vector<uint8_t> label(total, 0);  // 0 material, 1 this void, 2 other air
    std::vector<float> a(total, 0.0f);     // air fraction
    openvdb::tree::ValueAccessor<const FloatTree> ctAcc(ct);
    openvdb::tree::ValueAccessor<const BoolTree> airAcc(air), selfAcc(*w.mask);
    const double contrast = materialGrey - airGrey;
    for (int64_t z = 0; z < nz; ++z)
        for (int64_t y = 0; y < ny; ++y)
            for (int64_t x = 0; x < nx; ++x) {
                const Coord c = lo + Coord(int(x), int(y), int(z));
                const std::size_t i = at(x, y, z);
                a[i] = static_cast<float>((materialGrey - ctAcc.getValue(c)) / contrast);
                if (selfAcc.isValueOn(c)) label[i] = 1;
                else if (airAcc.isValueOn(c)) label[i] = 2;
            }
    // Chebyshev distances (capped) to this void and to other air: SHELL_VOXELS 26-dilations
    std::vector<uint8_t> dSelf(total, 255), dOther(total, 255);
    for (std::size_t i = 0; i < total; ++i) {
        if (label[i] == 1) dSelf[i] = 0;
        if (label[i] == 2) dOther[i] = 0;
    }
    auto dilate = [&](std::vector<uint8_t>& d) {
        for (int step = 1; step <= SHELL_VOXELS; ++step)
            for (int64_t z = 1; z + 1 < nz; ++z)
                for (int64_t y = 1; y + 1 < ny; ++y)
                    for (int64_t x = 1; x + 1 < nx; ++x) {
                        const std::size_t i = at(x, y, z);
                        if (d[i] != 255) continue;
                        bool hit = false;
                        for (int dz = -1; dz <= 1 && !hit; ++dz)
                            for (int dy = -1; dy <= 1 && !hit; ++dy)
                                for (int dx = -1; dx <= 1 && !hit; ++dx)
                                    if (d[at(x + dx, y + dy, z + dz)] == step - 1) hit = true;
                        if (hit) d[i] = static_cast<uint8_t>(step);
                    }
    };
    dilate(dSelf);
    dilate(dOther);
    double volume = 0;
    std::vector<float> weight(total, 0.0f);
    for (std::size_t i = 0; i < total; ++i) {
        float wgt = 0;
        if (label[i] == 1) wgt = 1;
        else if (label[i] == 0 && dSelf[i] <= SHELL_VOXELS) wgt = dSelf[i] < dOther[i] ? 1.0f : (dSelf[i] == dOther[i] ? 0.5f : 0.0f);
        weight[i] = wgt;
        volume += wgt * a[i];
    }
    w.volumeVoxels = volume;

    // boundary voxels -> max extent
    std::vector<openvdb::Vec3d> boundary;
    for (int64_t z = 1; z + 1 < nz; ++z)
        for (int64_t y = 1; y + 1 < ny; ++y)
            for (int64_t x = 1; x + 1 < nx; ++x) {
                if (label[at(x, y, z)] != 1) continue;
                if (label[at(x + 1, y, z)] != 1 || label[at(x - 1, y, z)] != 1 || label[at(x, y + 1, z)] != 1 ||
                    label[at(x, y - 1, z)] != 1 || label[at(x, y, z + 1)] != 1 || label[at(x, y, z - 1)] != 1)
                    boundary.emplace_back(lo.x() + x, lo.y() + y, lo.z() + z);
            }
    w.extentVoxels = maxVoxelDistance(boundary);

    if (!listed) return;
    // surface area: the 0.5 iso-surface of the air fraction of this void and its shell
    // (other air set to 0 so that neighbours do not add their walls)
    openvdb::FloatGrid field(0.0f);
    openvdb::FloatGrid::Accessor fAcc = field.getAccessor();
    for (int64_t z = 0; z < nz; ++z)
        for (int64_t y = 0; y < ny; ++y)
            for (int64_t x = 0; x < nx; ++x) {
                const std::size_t i = at(x, y, z);
                const float v = weight[i] > 0 ? std::clamp(a[i], 0.0f, 1.0f) : 0.0f;
                fAcc.setValueOn(Coord(int(x), int(y), int(z)), v);
            }
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(field, points, quads, 0.5);
    double area = 0, enclosed = 0;
    for (const openvdb::Vec4I& qd : quads) {
        const openvdb::Vec3d p0 = points[qd[0]], p1 = points[qd[1]], p2 = points[qd[2]], p3 = points[qd[3]];
        area += 0.5 * ((p2 - p0).cross(p3 - p1)).length();
        // divergence theorem over the two triangles (p0 p1 p2) and (p0 p2 p3)
        enclosed += (p0.dot(p1.cross(p2)) + p0.dot(p2.cross(p3))) / 6.0;
    }
    w.isoVolumeVoxels = std::abs(enclosed);
    w.areaVoxels = area;
}

/// Checks the parameters and the grid (not empty, cubic voxels, at least 3 voxels along each
/// axis); returns B, the grid's active bounding box.
CoordBBox checkedScanBox(const openvdb::FloatGrid& ct, const VoidParams& params, const std::string& sourceName)
{
    if (!(params.minDiameterVoxels >= 0) || !std::isfinite(params.minDiameterVoxels))
        throw ParameterError("min_diameter_voxels: must be >= 0 (got " + num(params.minDiameterVoxels) + ")");
    if (std::isinf(params.threshold))
        throw ParameterError("threshold: must be a finite grey value (or unset for Otsu)");
    const CoordBBox box = ct.evalActiveVoxelBoundingBox();
    if (box.empty() || ct.activeVoxelCount() == 0) throw InputError(sourceName + ": the CT grid is empty");
    const openvdb::Vec3d vs = ct.voxelSize();
    if (std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] || std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
        throw InputError(sourceName + ": voxels are not cubic (" + num(vs[0]) + " x " + num(vs[1]) + " x " +
                         num(vs[2]) + " mm); resample first");
    for (int a = 0; a < 3; ++a)
        if (box.dim()[a] < 3) throw InputError(sourceName + ": not a 3D volume (" + std::to_string(box.dim()[a]) +
                                               " voxels along axis " + std::to_string(a) + ")");
    return box;
}

/// Otsu's threshold over the histogram of B's grey values gMin..gMax; refuses a volume of one
/// phase (separability below MIN_SEPARABILITY).
double otsuThreshold(const FloatTree& tree, const CoordBBox& box, double gMin, double gMax,
                     const std::string& sourceName)
{
    if (!(gMax > gMin))
        throw InputError(sourceName + ": every voxel has the grey value " + num(gMin) +
                         ": no material or all material (nothing to tell air from material)");
    HistAcc proto;
    proto.lo = gMin;
    proto.scale = HISTOGRAM_BINS / (gMax - gMin) * (1 - 1e-12);
    auto add = [&proto](HistAcc& acc, double v, Index64 n) {
        acc.lo = proto.lo;
        acc.scale = proto.scale;
        acc.add(v, n);
    };
    HistAcc hist = reduceOverBox<HistAcc>(tree, box, add, add);
    const OtsuResult o = otsu(hist.bins, gMin, (gMax - gMin) / HISTOGRAM_BINS);
    if (o.separability < MIN_SEPARABILITY)
        throw InputError(sourceName + ": no air/material contrast: the grey values (" + num(gMin) + ".." +
                         num(gMax) + ") form one phase (Otsu separability " + num(o.separability) + " < " +
                         num(MIN_SEPARABILITY) + "): no material or all material");
    return o.threshold;
}

/// Step 1: the grey-value statistics over B and the threshold (out.threshold, Otsu's unless
/// given), checked to leave both material and air in B.
StatsAcc chooseThreshold(const FloatTree& tree, const CoordBBox& box, const VoidParams& params,
                         const std::string& sourceName, PartAnalysis& out)
{
    const StatsAcc stats = reduceOverBox<StatsAcc>(
        tree, box, [](StatsAcc& acc, double v, Index64 n) { acc.add(v, n); },
        [](StatsAcc& acc, double v, Index64 n) { acc.add(v, n); });
    if (!stats.s.finite) throw InputError(sourceName + ": grey values include NaN or infinity");
    const double gMin = stats.s.minV, gMax = stats.s.maxV;
    if (std::isnan(params.threshold)) {
        out.threshold = otsuThreshold(tree, box, gMin, gMax, sourceName);
        out.thresholdSource = "otsu";
    } else {
        out.threshold = params.threshold;
        out.thresholdSource = "given";
    }
    const double thr = out.threshold;
    if (gMax < thr)
        throw InputError(sourceName + ": no material: no voxel at or above the threshold " + num(thr) + " (" +
                         out.thresholdSource + "; grey values " + num(gMin) + ".." + num(gMax) + ")");
    if (gMin >= thr)
        throw InputError(sourceName + ": all material: no voxel below the threshold " + num(thr) + " (" +
                         out.thresholdSource + "; grey values " + num(gMin) + ".." + num(gMax) + ")");
    return stats;
}

/// Step 2: air = B minus material.
BoolTree::Ptr airOf(const BoolTree& material, const CoordBBox& box)
{
    BoolTree::Ptr air(new BoolTree(false));
    air->fill(box, true, true);
    air->topologyDifference(material);
    openvdb::tools::pruneInactive(*air);
    return air;
}

/// Step 3: the air's face-connected components: returns those touching a face of B (the
/// outside air), refused when there are none; each other one, an internal void, into `work`.
BoolTree::Ptr splitAir(const BoolTree& air, const CoordBBox& box, double thr, const std::string& sourceName,
                       std::vector<VoidWork>& work)
{
    MaskComponents components = faceConnectedComponents(air, box);
    BoolTree::Ptr outside = components.touching;
    for (BoolTree::Ptr& comp : components.enclosed) {
        VoidWork w;
        w.mask = comp;
        comp->evalActiveVoxelBoundingBox(w.bbox);
        w.voxels = comp->activeVoxelCount();
        work.push_back(std::move(w));
        comp.reset();
    }
    components.enclosed.clear();
    if (outside->activeVoxelCount() == 0)
        throw InputError(sourceName + ": all material at the border of the scan: no outside air to tell the part's "
                                      "surface from (threshold " + num(thr) + ")");
    return outside;
}

/// The grey levels of air and material away from any surface, and the material volume.
struct GreyLevels {
    double airGrey = 0, materialGrey = 0;
    double materialVoxels = 0;  // sum of the material fractions over the part and its rim
};

/// Step 4: the air grey value A (outside the part dilated by SHELL_VOXELS), the material grey
/// value M (the material eroded by SHELL_VOXELS) and the material volume over the dilated part.
GreyLevels partialVolumeLevels(const FloatTree& tree, const CoordBBox& box, const BoolTree& material,
                               const std::vector<VoidWork>& work, const StatsAcc& stats,
                               const std::string& sourceName)
{
    BoolTree filled(material);  // the part: material and its internal voids
    for (const VoidWork& w : work) filled.topologyUnion(*w.mask);
    openvdb::tools::prune(filled);
    openvdb::tools::dilateActiveValues(filled, SHELL_VOXELS, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::PRESERVE_TILES);
    filled.topologyIntersection(*[&] { BoolTree::Ptr b(new BoolTree(false)); b->fill(box, true, true); return b; }());
    const Moments part = greyOverMask(tree, filled);  // the part and a rim of 2 voxels
    const double deepAirCount = static_cast<double>(stats.s.count) - static_cast<double>(part.n);
    if (!(deepAirCount > 0))
        throw InputError(sourceName + ": the part fills the scan: no outside air farther than " +
                         std::to_string(SHELL_VOXELS) + " voxels from it to measure the air grey value");
    GreyLevels g;
    g.airGrey = (stats.s.sum - part.sum) / deepAirCount;
    BoolTree deep(material);
    openvdb::tools::prune(deep);
    openvdb::tools::erodeActiveValues(deep, SHELL_VOXELS, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                      openvdb::tools::PRESERVE_TILES);
    const Moments deepMaterial = greyOverMask(tree, deep);
    deep.clear();
    g.materialGrey = deepMaterial.n > 0 ? deepMaterial.sum / static_cast<double>(deepMaterial.n) : stats.s.maxV;
    if (!(g.materialGrey > g.airGrey))
        throw InputError(sourceName + ": material grey value " + num(g.materialGrey) + " is not above air " +
                         num(g.airGrey));
    g.materialVoxels = (part.sum - static_cast<double>(part.n) * g.airGrey) / (g.materialGrey - g.airGrey);
    return g;
}

/// Step 5a: measures every void (in parallel), then sorts them by volume, largest first (ties
/// by their box's min corner).
void measureVoids(std::vector<VoidWork>& work, const FloatTree& tree, const BoolTree& air, const GreyLevels& g,
                  double minVoxels)
{
    tbb::parallel_for(std::size_t(0), work.size(), [&](std::size_t i) {
        // listed or not is decided on the partial volume; measure first without the mesh
        measureVoid(work[i], tree, air, g.airGrey, g.materialGrey, false);
        if (work[i].volumeVoxels >= minVoxels && work[i].measuredByPartialVolume)
            measureVoid(work[i], tree, air, g.airGrey, g.materialGrey, true);
    });
    std::sort(work.begin(), work.end(), [](const VoidWork& a, const VoidWork& b) {
        if (a.volumeVoxels != b.volumeVoxels) return a.volumeVoxels > b.volumeVoxels;
        return a.bbox.min() < b.bbox.min();
    });
}

/// The listed void `w` with id `id`, in mm (voxelMm: a voxel's edge, voxelVolume: its volume).
VoidInfo voidInfo(const VoidWork& w, int id, const openvdb::FloatGrid& ct, NearestActive& nearest, double voxelMm,
                  double voxelVolume)
{
    VoidInfo v;
    v.id = id;
    v.voxels = static_cast<int64_t>(w.voxels);
    v.volumeMm3 = w.volumeVoxels * voxelVolume;
    v.equivalentDiameterMm = equivalentDiameter(v.volumeMm3);
    v.maxExtentMm = w.extentVoxels * voxelMm;
    // Sphericity of the iso-surface, its area against its own enclosed volume: on a blurred
    // scan the 0.5 iso-surface of a small pore lies inside its true surface, so pairing its
    // area with the partial volume would give values above 1.
    v.sphericity = w.areaVoxels > 0
                       ? std::cbrt(PI) * std::pow(6.0 * w.isoVolumeVoxels, 2.0 / 3.0) / w.areaVoxels
                       : 0.0;
    v.kind = w.flatness < CRACK_FLATNESS ? "crack" : "pore";
    const openvdb::Vec3d world = ct.transform().indexToWorld(w.centroid);
    v.centroidLps = Vec3d{world[0], world[1], world[2]};
    v.distanceToSurfaceMm = std::max(0.0, nearest.distance(w.centroid) - 0.5) * voxelMm;
    return v;
}

/// Step 5b: lists the voids of at least minVoxels (out.voids, ids 1.. in work's order) and
/// labels their voxels (out.voidLabels); counts the others as small. Returns the volume of all
/// voids (voxels).
double listVoids(const std::vector<VoidWork>& work, const openvdb::FloatGrid& ct, const BoolTree& outside,
                 double minVoxels, double voxelMm, double voxelVolume, PartAnalysis& out)
{
    out.voidLabels = openvdb::Int32Grid::create(0);
    out.voidLabels->setTransform(ct.transform().copy());
    out.voidLabels->setName("void_labels");
    openvdb::Int32Grid::Accessor labelAcc = out.voidLabels->getAccessor();
    NearestActive nearest(outside);
    double voidVoxels = 0;
    for (const VoidWork& w : work) {
        voidVoxels += w.volumeVoxels;
        if (w.volumeVoxels < minVoxels) {
            ++out.smallVoidCount;
            out.smallVoidVolumeMm3 += w.volumeVoxels * voxelVolume;
            continue;
        }
        const VoidInfo v = voidInfo(w, static_cast<int>(out.voids.size()) + 1, ct, nearest, voxelMm, voxelVolume);
        for (auto it = w.mask->cbeginValueOn(); it; ++it) labelAcc.setValueOn(it.getCoord(), v.id);
        out.voids.push_back(v);
    }
    return voidVoxels;
}

/// `mask`, pruned, as a grid with the CT's transform and the given name.
openvdb::BoolGrid::Ptr maskGrid(const BoolTree::Ptr& mask, const openvdb::FloatGrid& ct, const std::string& name)
{
    openvdb::tools::prune(*mask);
    openvdb::BoolGrid::Ptr grid = openvdb::BoolGrid::create(mask);
    grid->setTransform(ct.transform().copy());
    grid->setName(name);
    return grid;
}

} // namespace

double equivalentDiameter(double volume)
{
    return volume > 0 ? std::cbrt(6.0 * volume / PI) : 0.0;
}

double maxVoxelDistance(const std::vector<openvdb::Vec3d>& voxelsIn)
{
    if (voxelsIn.size() < 2) return 0.0;
    const std::vector<openvdb::Vec3d>* cand = &voxelsIn;
    std::vector<openvdb::Vec3d> extremes;
    if (voxelsIn.size() > 3000) {
        // extreme voxels along 512 directions of a Fibonacci half-sphere (both ends of each)
        const int nDir = 512;
        std::vector<std::size_t> idx;
        for (int d = 0; d < nDir; ++d) {
            const double z = 1.0 - (d + 0.5) / nDir;  // 0..1: a half-sphere; -dir gives the other end
            const double r = std::sqrt(std::max(0.0, 1 - z * z)), phi = d * 2.399963229728653;
            const openvdb::Vec3d dir(r * std::cos(phi), r * std::sin(phi), z);
            std::size_t iMin = 0, iMax = 0;
            double vMin = std::numeric_limits<double>::infinity(), vMax = -vMin;
            for (std::size_t i = 0; i < voxelsIn.size(); ++i) {
                const double v = voxelsIn[i].dot(dir);
                if (v < vMin) { vMin = v; iMin = i; }
                if (v > vMax) { vMax = v; iMax = i; }
            }
            idx.push_back(iMin);
            idx.push_back(iMax);
        }
        std::sort(idx.begin(), idx.end());
        idx.erase(std::unique(idx.begin(), idx.end()), idx.end());
        for (std::size_t i : idx) extremes.push_back(voxelsIn[i]);
        cand = &extremes;
    }
    double best2 = 0;
    const std::vector<openvdb::Vec3d>& v = *cand;
    for (std::size_t i = 0; i < v.size(); ++i)
        for (std::size_t j = i + 1; j < v.size(); ++j) best2 = std::max(best2, (v[i] - v[j]).lengthSqr());
    return std::sqrt(best2);
}

PartAnalysis analysePart(const openvdb::FloatGrid& ct, const VoidParams& params, const std::string& sourceName,
                         Progress* progress)
{
    const CoordBBox box = checkedScanBox(ct, params, sourceName);
    const FloatTree& tree = ct.tree();
    const openvdb::Vec3d vs = ct.voxelSize();
    const double voxelMm = vs[0], voxelVolume = vs[0] * vs[1] * vs[2];
    reportProgress(progress, 0.0, "histogram");

    // ---- 1. histogram and threshold
    PartAnalysis out;
    const StatsAcc stats = chooseThreshold(tree, box, params, sourceName, out);
    const double thr = out.threshold;
    reportProgress(progress, 0.1, "material and air");

    // ---- 2. material, air
    BoolTree::Ptr material = maskFromGrey(tree, box, [thr](float v) { return v >= thr; });
    BoolTree::Ptr air = airOf(*material, box);

    // ---- 3. air components: border-touching ones are outside air
    reportProgress(progress, 0.2, "air components");
    std::vector<VoidWork> work;
    BoolTree::Ptr outside = splitAir(*air, box, thr, sourceName, work);

    // ---- 4. partial volume: air and material grey levels away from any surface
    reportProgress(progress, 0.4, "partial volume");
    const GreyLevels grey = partialVolumeLevels(tree, box, *material, work, stats, sourceName);

    // ---- 5. per void
    reportProgress(progress, 0.6, "voids");
    const double minVoxels = PI / 6.0 * std::pow(params.minDiameterVoxels, 3);
    measureVoids(work, tree, *air, grey, minVoxels);
    air.reset();
    const double voidVoxels = listVoids(work, ct, *outside, minVoxels, voxelMm, voxelVolume, out);
    out.materialVolumeMm3 = grey.materialVoxels * voxelVolume;
    out.voidVolumeMm3 = voidVoxels * voxelVolume;
    out.porosityPercent = 100.0 * out.voidVolumeMm3 / (out.materialVolumeMm3 + out.voidVolumeMm3);

    out.material = maskGrid(material, ct, "material");
    out.outsideAir = maskGrid(outside, ct, "outside_air");
    reportProgress(progress, 1.0, "voids done");
    return out;
}

} // namespace flyover
