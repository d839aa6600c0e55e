// External masks -> lumen level set (constrained smoothing of the binary surface, volume
// restored by a constant offset), and lumen level set -> mask image on any lattice.
#include "colon/lumen_mask.h"
#include "volume/vec3.h"

#include "volume/error.h"
#include "volume/ingest.h"
#include "volume/segment_tools.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <iomanip>
#include <optional>
#include <set>
#include <sstream>

namespace flyover {

namespace {

using openvdb::BoolTree;
using openvdb::Coord;
using openvdb::FloatGrid;
using openvdb::FloatTree;
using BoolLeaf = BoolTree::LeafNodeType;
using FloatLeaf = FloatTree::LeafNodeType;
using BoolConstAccessor = openvdb::tree::ValueAccessor<const BoolTree>;
using FloatConstAccessor = openvdb::tree::ValueAccessor<const FloatTree>;
using detail::Neighbours;

/// A mask voxel centre counts as inside (outside) where the resampled indicator is at least
/// 1 - CONSTRAINT_TOLERANCE (at most CONSTRAINT_TOLERANCE); on the mask's own lattice the
/// indicator is exactly 0 or 1 at every centre, so every centre is constrained; resampled,
/// the output voxel nearest to each mask centre is constrained to that centre's side.
constexpr float CONSTRAINT_TOLERANCE = 0.25f;
/// How far from a constrained voxel centre (in output voxels) the smoothed surface must stay.
constexpr float CONSTRAINT_MARGIN_VOXELS = 0.05f;
/// A plausible colon's volume over that of the largest ball inside it.
constexpr double PLAUSIBLE_ELONGATION = 2.0;

bool holdsLabel(float v, int label)
{
    if (label == 0) return v > 0.5f;
    return std::isfinite(v) && std::lround(v) == label;
}

/// The label voxels, in the mask's index space, read a slab at a time.
BoolTree::Ptr readLabel(ImageSource& mask, int label, MaskSummary& summary, Progress* progress)
{
    const ImageGeometry& g = mask.geometry();
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    constexpr int64_t SLAB = 8;
    std::vector<float> slab(static_cast<std::size_t>(nx * ny * SLAB));
    auto tree = std::make_shared<BoolTree>(false);
    openvdb::tree::ValueAccessor<BoolTree> acc(*tree);
    std::set<int> present;
    float lastPresent = 0.0f;  // the last value inserted: runs of one label skip the set
    for (int64_t k0 = 0; k0 < nz; k0 += SLAB) {
        const int64_t k1 = std::min(nz, k0 + SLAB);
        mask.readSlices(k0, k1, slab.data());
        std::size_t v = 0;
        for (int64_t k = k0; k < k1; ++k)
            for (int64_t j = 0; j < ny; ++j)
                for (int64_t i = 0; i < nx; ++i, ++v) {
                    const float value = slab[v];
                    if (value != 0.0f && value != lastPresent && std::isfinite(value) && present.size() < 64) {
                        present.insert(int(std::lround(value)));
                        lastPresent = value;
                    }
                    if (holdsLabel(value, label)) acc.setValueOn(Coord(int(i), int(j), int(k)), true);
                }
        reportProgress(progress, 0.2 * double(k1) / double(nz), "read mask");
    }
    summary.labelsPresent.assign(present.begin(), present.end());
    summary.labelVoxels = static_cast<int64_t>(tree->activeVoxelCount());
    return tree;
}

openvdb::Vec3d toVdb(const Vec3d& v) { return {v.x, v.y, v.z}; }
Vec3d fromVdb(const openvdb::Vec3d& v) { return {v[0], v[1], v[2]}; }

/// When the mask's voxel centres are output voxel centres (same spacing and axes, origin
/// on the output lattice): the integer offset from mask index to output index.
std::optional<Coord> latticeOffset(const ImageGeometry& g, const openvdb::math::Transform& xf)
{
    const double h = xf.voxelSize()[0];
    for (int c = 0; c < 3; ++c)
        if (std::abs(g.spacingMm[c] - h) > 1e-6 * h) return std::nullopt;
    const openvdb::Vec3d o = xf.worldToIndex(toVdb(g.worldFromIndex({0, 0, 0})));
    const Coord offset = Coord::round(o);
    for (int c = 0; c < 3; ++c)
        if (std::abs(o[c] - offset[c]) > 1e-4) return std::nullopt;
    const Vec3d steps[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (const Vec3d& p : steps) {
        const openvdb::Vec3d ijk = xf.worldToIndex(toVdb(g.worldFromIndex(p))) - o;
        for (int c = 0; c < 3; ++c)
            if (std::abs(ijk[c] - p[c]) > 1e-4) return std::nullopt;
    }
    return offset;
}

/// The mask's indicator (1 inside, 0 outside) on the output lattice: the label voxels
/// shifted by `offset` when the lattices agree, else trilinear samples of the label at the
/// output voxel centres (active where > 0).
FloatTree::Ptr indicatorOnGrid(const BoolTree& label, const ImageGeometry& g,
                               const openvdb::math::Transform& xf, const std::optional<Coord>& offset)
{
    if (offset) {
        auto out = std::make_shared<FloatTree>(0.0f);
        openvdb::tree::ValueAccessor<FloatTree> acc(*out);
        for (auto it = label.cbeginValueOn(); it; ++it) acc.setValue(it.getCoord() + *offset, 1.0f);
        return out;
    }
    // The label as a dense bit set over the mask's lattice (1 bit a voxel: 11 MB for
    // 512 x 512 x 460), so that each trilinear sample reads bits instead of tree look-ups.
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    std::vector<std::uint64_t> bits(static_cast<std::size_t>((nx * ny * nz + 63) / 64), 0);
    for (auto it = label.cbeginValueOn(); it; ++it) {
        const Coord m = it.getCoord();
        const int64_t v = (int64_t(m.z()) * ny + m.y()) * nx + m.x();
        bits[std::size_t(v >> 6)] |= std::uint64_t(1) << (v & 63);
    }
    auto isLabel = [&](const Coord& m) {
        if (m.x() < 0 || m.y() < 0 || m.z() < 0 || m.x() >= nx || m.y() >= ny || m.z() >= nz) return false;
        const int64_t v = (int64_t(m.z()) * ny + m.y()) * nx + m.x();
        return ((bits[std::size_t(v >> 6)] >> (v & 63)) & 1u) != 0;
    };
    // The output leaves that may hold a positive sample: those meeting the output index box
    // of a label leaf grown by one mask voxel (a sample reads the label voxels within one
    // mask voxel of its position), grown by one output voxel against rounding.
    auto out = std::make_shared<FloatTree>(0.0f);
    {
        constexpr int LEAF = int(BoolLeaf::DIM);
        for (auto leaf = label.cbeginLeaf(); leaf; ++leaf) {
            const Coord o = leaf->origin();
            Coord lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
            for (int corner = 0; corner < 8; ++corner) {
                const Vec3d m((corner & 1) ? o.x() + LEAF : o.x() - 1.0, (corner & 2) ? o.y() + LEAF : o.y() - 1.0,
                              (corner & 4) ? o.z() + LEAF : o.z() - 1.0);
                const openvdb::Vec3d u = xf.worldToIndex(toVdb(g.worldFromIndex(m)));
                for (int a = 0; a < 3; ++a) {
                    lo[a] = std::min(lo[a], int(std::floor(u[a])) - 1);
                    hi[a] = std::max(hi[a], int(std::ceil(u[a])) + 1);
                }
            }
            for (int x = lo.x() & ~(LEAF - 1); x <= hi.x(); x += LEAF)
                for (int y = lo.y() & ~(LEAF - 1); y <= hi.y(); y += LEAF)
                    for (int z = lo.z() & ~(LEAF - 1); z <= hi.z(); z += LEAF) out->touchLeaf(Coord(x, y, z));
        }
    }
    openvdb::tree::LeafManager<FloatTree> leaves(*out);
    leaves.foreach([&](FloatLeaf& leaf, std::size_t) {
        // A leaf whose samples read no label voxel stays empty: the mask index box of its
        // corners (every voxel's position lies between them, the maps being affine), grown by
        // a voxel against rounding, holds no label bit.
        {
            constexpr double BIG = std::numeric_limits<double>::max();
            Vec3d lo(BIG, BIG, BIG), hi(-BIG, -BIG, -BIG);
            const Coord o = leaf.origin();
            constexpr int LAST = int(FloatLeaf::DIM) - 1;
            for (int corner = 0; corner < 8; ++corner) {
                const Coord c = o.offsetBy((corner & 1) ? LAST : 0, (corner & 2) ? LAST : 0, (corner & 4) ? LAST : 0);
                const Vec3d u = g.indexFromWorld(fromVdb(xf.indexToWorld(c)));
                for (int a = 0; a < 3; ++a) {
                    lo[a] = std::min(lo[a], u[a]);
                    hi[a] = std::max(hi[a], u[a]);
                }
            }
            bool any = false;
            for (int64_t k = std::max<int64_t>(0, int64_t(std::floor(lo.z)) - 1);
                 !any && k <= std::min<int64_t>(nz - 1, int64_t(std::floor(hi.z)) + 2); ++k)
                for (int64_t j = std::max<int64_t>(0, int64_t(std::floor(lo.y)) - 1);
                     !any && j <= std::min<int64_t>(ny - 1, int64_t(std::floor(hi.y)) + 2); ++j)
                    for (int64_t i = std::max<int64_t>(0, int64_t(std::floor(lo.x)) - 1);
                         !any && i <= std::min<int64_t>(nx - 1, int64_t(std::floor(hi.x)) + 2); ++i)
                        any = isLabel(Coord(int(i), int(j), int(k)));
            if (!any) return;
            // Likewise a leaf whose box (the same, out-of-image indices included) holds only label
            // voxels: every sample's weights sum to 1 (to within 1e-15, which rounds to 1.0f), and
            // the constraint keeps 1; so every voxel is 1.
            bool all = true;
            for (int64_t k = int64_t(std::floor(lo.z)) - 1; all && k <= int64_t(std::floor(hi.z)) + 2; ++k)
                for (int64_t j = int64_t(std::floor(lo.y)) - 1; all && j <= int64_t(std::floor(hi.y)) + 2; ++j)
                    for (int64_t i = int64_t(std::floor(lo.x)) - 1; all && i <= int64_t(std::floor(hi.x)) + 2; ++i)
                        all = isLabel(Coord(int(i), int(j), int(k)));
            if (all) {
                leaf.fill(1.0f, true);
                return;
            }
        }
        for (openvdb::Index pos = 0; pos < FloatLeaf::SIZE; ++pos) {
            const Coord c = leaf.offsetToGlobalCoord(pos);
            const Vec3d u = g.indexFromWorld(fromVdb(xf.indexToWorld(c)));
            const Coord base(int(std::floor(u.x)), int(std::floor(u.y)), int(std::floor(u.z)));
            const double fx = u.x - base.x(), fy = u.y - base.y(), fz = u.z - base.z();
            double value = 0;
            for (int dz = 0; dz < 2; ++dz)
                for (int dy = 0; dy < 2; ++dy)
                    for (int dx = 0; dx < 2; ++dx)
                        if (isLabel(base.offsetBy(dx, dy, dz)))
                            value += (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) * (dz ? fz : 1 - fz);
            value = std::min(value, 1.0);
            // The output voxel nearest to a mask centre takes that centre's side (constrained),
            // so that a part or a wall one mask voxel thick is neither lost nor opened between
            // the samples: a trilinear sample between slices is often free (0.25-0.75) there.
            const Coord m(int(std::lround(u.x)), int(std::lround(u.y)), int(std::lround(u.z)));
            const Vec3d mw = g.worldFromIndex({double(m.x()), double(m.y()), double(m.z())});
            if (Coord::round(xf.worldToIndex(toVdb(mw))) == c)
                value = isLabel(m) ? std::max(value, 1.0 - CONSTRAINT_TOLERANCE)
                                   : std::min(value, double(CONSTRAINT_TOLERANCE));
            if (value > 1e-6) leaf.setValueOn(pos, static_cast<float>(value));
        }
    });
    detail::pruneInactive(*out);
    return out;
}

/// The constraints of a binary mask at an output voxel: its centre must stay inside (value
/// at most -margin), outside (at least +margin), or is free.
inline float constrained(float phi, float indicator, float marginMm)
{
    if (indicator >= 1.0f - CONSTRAINT_TOLERANCE) return std::min(phi, -marginMm);
    if (indicator <= CONSTRAINT_TOLERANCE) return std::max(phi, marginMm);
    return phi;
}

/// The sub-voxel volume (in voxels) of the level set phi - offset after the constraints,
/// for offsets in [-maxOffsetMm, maxOffsetMm]: the sum over the active voxels of
/// clamp(0.5 - phi' / h, 0, 1), phi' = the constrained value of phi - offset, which keeps every
/// mask centre on its side. Each voxel's term is monotone in the offset, so a voxel whose term
/// is the same at both ends of the range contributes a constant (summed once); the others
/// (about a voxel either side of the surface) are kept in a flat list, which solve()'s
/// bisection narrows as its bracket narrows.
class VolumeOfOffset {
public:
    VolumeOfOffset(const FloatTree& phi, const FloatTree& indicator, double maxOffsetMm, double h, float marginMm)
        : mH(h), mMarginMm(marginMm)
    {
        openvdb::tree::LeafManager<const FloatTree> leaves(phi);
        std::vector<double> fixed(leaves.leafCount(), 0.0);
        std::vector<std::vector<std::pair<float, float>>> band(leaves.leafCount());
        leaves.foreach([&](const FloatLeaf& leaf, std::size_t n) {
            FloatConstAccessor indAcc(indicator);
            const FloatLeaf* indLeaf = indicator.probeConstLeaf(leaf.origin());
            double s = 0;
            for (auto it = leaf.cbeginValueOn(); it; ++it) {
                const float ind = indLeaf ? indLeaf->getValue(it.pos()) : indAcc.getValue(it.getCoord());
                const double lo = term(*it, ind, -maxOffsetMm), hi = term(*it, ind, maxOffsetMm);
                if (lo == hi) s += lo;
                else band[n].emplace_back(*it, ind);
            }
            fixed[n] = s;
        });
        for (double v : fixed) mFixed += v;
        for (const auto& b : band) mBand.insert(mBand.end(), b.begin(), b.end());
    }

    /// The offset in [lo, hi] at which the volume reaches targetVoxels, by `iterations`
    /// bisection steps. After each step the band keeps only the voxels whose term still
    /// differs between the ends of the bracket (the others are constant on it and are summed
    /// once), so the band halves at each step: a few passes over it instead of one per step.
    /// The decisions are those of bisecting the whole band's sum (the sums differ by rounding
    /// only, ~1e-9 voxels, far below what separates them from the target at any step).
    double solve(double targetVoxels, double lo, double hi, int iterations)
    {
        // Each voxel keeps its terms at both ends of the bracket and at its midpoint, so that
        // a step evaluates one term per voxel (the new end's term is the midpoint's).
        struct Voxel {
            float phi, ind;
            double atLo, atHi, atMid;
        };
        std::vector<Voxel> band(mBand.size());
        for (std::size_t n = 0; n < mBand.size(); ++n) {
            const auto& [phi, ind] = mBand[n];
            band[n] = {phi, ind, term(phi, ind, lo), term(phi, ind, hi), 0.0};
        }
        double fixed = mFixed;
        for (int i = 0; i < iterations; ++i) {
            const double mid = 0.5 * (lo + hi);
            double s = fixed;
            for (Voxel& e : band) s += e.atMid = term(e.phi, e.ind, mid);
            const bool raiseLo = s < targetVoxels;
            (raiseLo ? lo : hi) = mid;
            std::size_t kept = 0;
            for (Voxel e : band) {
                (raiseLo ? e.atLo : e.atHi) = e.atMid;
                if (e.atLo == e.atHi) fixed += e.atLo;
                else band[kept++] = e;
            }
            band.resize(kept);
        }
        return 0.5 * (lo + hi);
    }

private:
    double term(float phi, float indicator, double offsetMm) const
    {
        const float v = constrained(float(phi - offsetMm), indicator, mMarginMm);
        return std::clamp(0.5 - v / mH, 0.0, 1.0);
    }

    double mH;
    float mMarginMm;
    double mFixed = 0;
    std::vector<std::pair<float, float>> mBand;
};

/// Jacobi iterations of the discrete Laplacian (each replaces a voxel by the mean of its six
/// neighbours: diffusion for 1/6 voxel^2, i.e. sigma^2 grows by h^2 / 3) on the voxels of
/// `work`, each followed by the constraints: phi <= -margin at inside centres, >= +margin at
/// outside centres.
void constrainedSmoothing(FloatTree& phi, const BoolTree& work, const FloatTree& indicator,
                          int iterations, float marginMm)
{
    openvdb::tree::LeafManager<const BoolTree> leaves(work);
    const std::size_t count = leaves.leafCount();
    std::vector<std::array<float, FloatLeaf::SIZE>> next(count);
    // Per work leaf, found once: its phi leaf (work has phi's topology), the six face-neighbour
    // phi leaves (-/+ x, -/+ y, -/+ z; nullptr: read through an accessor) and its indicator
    // leaf, so that the iterations read neighbours by offset instead of tree look-ups.
    constexpr int DIM = int(FloatLeaf::DIM);
    constexpr int STRIDE[3] = {DIM * DIM, DIM, 1};
    std::vector<FloatLeaf*> phiLeaf(count);
    std::vector<std::array<const FloatLeaf*, 6>> nbLeaf(count);
    std::vector<const FloatLeaf*> indLeaf(count);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 64), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t n = r.begin(); n != r.end(); ++n) {
            const Coord o = leaves.leaf(n).origin();
            phiLeaf[n] = phi.probeLeaf(o);
            indLeaf[n] = indicator.probeConstLeaf(o);
            for (int axis = 0; axis < 3; ++axis)
                for (int side = 0; side < 2; ++side) {
                    Coord q = o;
                    q[axis] += side ? -DIM : DIM;  // slot 2 axis: +, 2 axis + 1: -
                    nbLeaf[n][std::size_t(2 * axis + side)] = phi.probeConstLeaf(q);
                }
        }
    });
    for (int iter = 0; iter < iterations; ++iter) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 8),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            FloatConstAccessor phiAcc(phi), indAcc(indicator);
            for (std::size_t n = r.begin(); n != r.end(); ++n) {
                const FloatLeaf* centre = phiLeaf[n];
                if (!centre) continue;
                const float* c = centre->buffer().data();
                const float* ind = indLeaf[n] ? indLeaf[n]->buffer().data() : nullptr;
                for (auto it = leaves.leaf(n).cbeginValueOn(); it; ++it) {
                    const int pos = int(it.pos());
                    const int local[3] = {pos >> 6, (pos >> 3) & 7, pos & 7};
                    // The six neighbours in the order +x, -x, +y, -y, +z, -z (the sum's order).
                    float sum = 0;
                    for (int axis = 0; axis < 3; ++axis)
                        for (int side = 0; side < 2; ++side) {
                            const bool plus = side == 0;
                            float v;
                            if (plus ? local[axis] < DIM - 1 : local[axis] > 0) {
                                v = c[plus ? pos + STRIDE[axis] : pos - STRIDE[axis]];
                            } else if (const FloatLeaf* other = nbLeaf[n][std::size_t(2 * axis + side)]) {
                                v = other->buffer().data()[plus ? pos - (DIM - 1) * STRIDE[axis]
                                                                : pos + (DIM - 1) * STRIDE[axis]];
                            } else {
                                Coord q = it.getCoord();
                                q[axis] += plus ? 1 : -1;
                                v = phiAcc.getValue(q);
                            }
                            sum += v;
                        }
                    const float indicatorValue = ind ? ind[pos] : indAcc.getValue(it.getCoord());
                    next[n][std::size_t(pos)] = constrained(sum / 6.0f, indicatorValue, marginMm);
                }
            }
        });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 8),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t n = r.begin(); n != r.end(); ++n) {
                FloatLeaf* target = phiLeaf[n];
                if (!target) continue;
                for (auto it = leaves.leaf(n).cbeginValueOn(); it; ++it)
                    target->setValueOnly(it.pos(), next[n][it.pos()]);
            }
        });
    }
}

openvdb::math::Transform::Ptr outputTransform(const ImageGeometry& g, const FloatGrid* reference)
{
    if (reference) {
        const auto& xf = reference->transform();
        const openvdb::Vec3d vs = xf.voxelSize();
        if (!xf.isLinear() || !(vs[0] > 0) || std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] ||
            std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
            throw InputError("segmentFromMask: the reference grid's voxels are not cubic");
        return xf.copy();
    }
    const double voxelMm = std::min({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z});
    return makeGridTransform(g.originMm, g.direction, voxelMm);
}

std::string labelsText(const std::vector<int>& labels)
{
    if (labels.empty()) return "none: every voxel is 0";
    std::ostringstream s;
    for (std::size_t i = 0; i < labels.size(); ++i) s << (i ? ", " : "") << labels[i];
    if (labels.size() >= 64) s << ", ...";
    return s.str();
}

/// Finds the rectal tube in the indicator (voxels >= 0.5) and turns its voxels off (outside).
RectalTube cutMaskRectalTube(FloatTree& indicator, const ImageGeometry& g, const openvdb::math::Transform& xf)
{
    BoolTree inside(indicator, false, true, openvdb::TopologyCopy());
    {
        openvdb::tree::LeafManager<BoolTree> leaves(inside);
        leaves.foreach([&](BoolLeaf& leaf, std::size_t) {
            const FloatLeaf* src = indicator.probeConstLeaf(leaf.origin());
            if (!src) return;
            for (auto it = src->cbeginValueOn(); it; ++it)
                if (!(*it >= 0.5f)) leaf.setValueOff(it.pos(), false);
        });
    }
    detail::pruneInactive(inside);
    detail::TubeSearch search;
    search.acceptLowestEnd = true;
    search.outside = [&](const Coord& c) {
        const Vec3d u = g.indexFromWorld(fromVdb(xf.indexToWorld(c)));
        for (int a = 0; a < 3; ++a)
            if (u[a] < -0.5 || u[a] > double(g.size[std::size_t(a)]) - 0.5) return true;
        return false;
    };
    RectalTube tube;
    BoolTree::Ptr fill;
    const BoolTree::Ptr cut = detail::findRectalTube(inside, xf, search, tube, &fill);
    if (!tube.found) return tube;
    openvdb::tree::ValueAccessor<FloatTree> acc(indicator);
    for (auto it = cut->cbeginValueOn(); it; ++it) acc.setValueOff(it.getCoord(), 0.0f);
    // The tube inside the rectum's air becomes lumen (rectal_tube.h, step 5).
    if (fill)
        for (auto it = fill->cbeginValueOn(); it; ++it) acc.setValueOn(it.getCoord(), 1.0f);
    return tube;
}

/// The number of label voxels (mask index space, lattice `g`) beyond the reference CT's active
/// box, on the output lattice `xf`.
/// @throw InputError when no label voxel lies within it (the mask does not overlap the CT)
int64_t voxelsOutsideReference(const BoolTree& label, const ImageGeometry& g, const openvdb::math::Transform& xf,
                               const FloatGrid& reference, const std::string& name)
{
    const openvdb::CoordBBox box = reference.evalActiveVoxelBoundingBox();
    openvdb::Index64 outside = 0;
    for (auto it = label.cbeginValueOn(); it; ++it) {
        const Coord m = it.getCoord();
        const Vec3d w = g.worldFromIndex({double(m.x()), double(m.y()), double(m.z())});
        const openvdb::Vec3d ijk = xf.worldToIndex(toVdb(w));
        bool in = true;
        for (int c = 0; c < 3; ++c) in = in && ijk[c] >= box.min()[c] - 0.5 && ijk[c] <= box.max()[c] + 0.5;
        outside += in ? 0 : 1;
    }
    if (outside == label.activeVoxelCount()) {
        const openvdb::Vec3d lo = xf.indexToWorld(box.min()), hi = xf.indexToWorld(box.max());
        std::ostringstream msg;
        msg << std::fixed << std::setprecision(1) << name
            << ": the mask does not overlap the CT (no label voxel lies within the CT's box, "
            << "LPS mm from (" << std::min(lo[0], hi[0]) << ", " << std::min(lo[1], hi[1]) << ", "
            << std::min(lo[2], hi[2]) << ") to (" << std::max(lo[0], hi[0]) << ", "
            << std::max(lo[1], hi[1]) << ", " << std::max(lo[2], hi[2])
            << ")); are they from the same scan?";
        throw InputError(msg.str());
    }
    return static_cast<int64_t>(outside);
}

/// f0 = 0.5 - indicator on the indicator's active voxels dilated by `shellVoxels`
/// (background 0.5).
FloatTree::Ptr initialField(const FloatTree& indicator, int shellVoxels)
{
    BoolTree region(indicator, false, true, openvdb::TopologyCopy());
    detail::dilateVoxels(region, shellVoxels, Neighbours::All);
    auto f = std::make_shared<FloatTree>(region, 0.5f, openvdb::TopologyCopy());
    openvdb::tree::LeafManager<FloatTree> leaves(*f);
    leaves.foreach([&](FloatLeaf& leaf, std::size_t) {
        FloatConstAccessor indAcc(indicator);
        const FloatLeaf* indLeaf = indicator.probeConstLeaf(leaf.origin());
        for (auto it = leaf.beginValueOn(); it; ++it)
            it.setValue(0.5f - (indLeaf ? indLeaf->getValue(it.pos()) : indAcc.getValue(it.getCoord())));
    });
    return f;
}

/// Deactivates the voxels of `f` deeper inside than reachMm + 3 voxels (of h mm), their values
/// kept; returns them.
BoolTree::Ptr leaveOutDeepVoxels(FloatTree& f, float reachMm, double h)
{
    auto deep = std::make_shared<BoolTree>(f, false, openvdb::TopologyCopy());
    openvdb::tree::LeafManager<BoolTree> leaves(*deep);
    leaves.foreach([&](BoolLeaf& leaf, std::size_t) {
        const FloatLeaf* src = f.probeConstLeaf(leaf.origin());
        if (!src) return;
        for (auto it = src->cbeginValueOn(); it; ++it)
            if (!(*it < 0.0f)) leaf.setValueOff(it.pos(), false);
    });
    detail::erodeVoxels(*deep, int(std::ceil(reachMm / h)) + 3, Neighbours::All);
    openvdb::tree::LeafManager<const BoolTree> deepLeaves(*deep);
    deepLeaves.foreach([&](const BoolLeaf& leaf, std::size_t) {
        FloatLeaf* target = f.probeLeaf(leaf.origin());
        if (!target) return;
        for (auto it = leaf.cbeginValueOn(); it; ++it) target->setValueOff(it.pos());
    });
    return deep;
}

/// Constrained smoothing of the distance `phi` within reachMm of the surface, then the final
/// sweep over the whole region of `fGrid` (the field phi was swept from, less the `deep`
/// voxels); returns its distance.
FloatGrid::Ptr smoothAndRedistance(FloatTree& phi, FloatGrid& fGrid, const BoolTree& deep, const FloatTree& indicator,
                                   int iterations, float reachMm, float marginMm, Progress* progress)
{
    FloatTree& f = fGrid.tree();
    BoolTree work(phi, false, true, openvdb::TopologyCopy());
    {
        openvdb::tree::LeafManager<BoolTree> leaves(work);
        leaves.foreach([&](BoolLeaf& leaf, std::size_t) {
            const FloatLeaf* src = phi.probeConstLeaf(leaf.origin());
            for (auto it = src->cbeginValueOn(); it; ++it)
                if (!(std::abs(*it) < reachMm)) leaf.setValueOff(it.pos(), false);
        });
    }
    reportProgress(progress, 0.5, "constrained smoothing");
    constrainedSmoothing(phi, work, indicator, iterations, marginMm);
    // The final sweep over the whole region: the band's values (the smoothed surface),
    // the deep voxels back in with their sign.
    openvdb::tree::LeafManager<const FloatTree> bandLeaves(phi);
    bandLeaves.foreach([&](const FloatLeaf& leaf, std::size_t) {
        FloatLeaf* target = f.probeLeaf(leaf.origin());
        if (!target) return;
        for (auto it = leaf.cbeginValueOn(); it; ++it) target->setValueOnly(it.pos(), *it);
    });
    f.topologyUnion(deep);
    reportProgress(progress, 0.6, "mask level set: whole lumen distance");
    return detail::redistance(fGrid);
}

/// Shifts `phi` by the constant offset (bisection, within one voxel of h mm) at which its
/// sub-voxel volume is targetVoxels, the constraints applied after it.
void restoreVolume(FloatTree& phi, const FloatTree& indicator, double targetVoxels, double h, float marginMm)
{
    VolumeOfOffset volume(phi, indicator, h, h, marginMm);
    const float volumeOffsetMm = static_cast<float>(volume.solve(targetVoxels, -h, h, 40));
    openvdb::tree::LeafManager<FloatTree> leaves(phi);
    leaves.foreach([&](FloatLeaf& leaf, std::size_t) {
        FloatConstAccessor indAcc(indicator);
        const FloatLeaf* indLeaf = indicator.probeConstLeaf(leaf.origin());
        for (auto it = leaf.beginValueOn(); it; ++it)
            it.setValue(constrained(*it - volumeOffsetMm,
                                    indLeaf ? indLeaf->getValue(it.pos()) : indAcc.getValue(it.getCoord()),
                                    marginMm));
    });
}

} // namespace

LumenSegmentation segmentFromMask(ImageSource& mask, const SegmentParams& params,
                                  const FloatGrid* reference, Progress* progress, MaskSummary* summaryOut)
{
    validateSegmentParams(params);
    if (!mask.isRegular())
        throw InputError(mask.name() + ": the mask's slices are not on a regular lattice");
    MaskSummary summary;
    summary.geometry = mask.geometry();
    const ImageGeometry& g = summary.geometry;
    reportProgress(progress, 0.0, "read mask");
    BoolTree::Ptr label = readLabel(mask, params.maskLabel, summary, progress);
    if (label->empty()) {
        std::ostringstream msg;
        msg << mask.name() << ": no voxel holds "
            << (params.maskLabel == 0 ? std::string("a non-zero label") : "label " + std::to_string(params.maskLabel))
            << " (labels present: " << labelsText(summary.labelsPresent) << ")";
        throw InputError(msg.str());
    }

    const openvdb::math::Transform::Ptr xf = outputTransform(g, reference);
    const double h = xf->voxelSize()[0];
    const double voxelMl = std::abs(xf->voxelVolume()) / 1000.0;
    // The mask must overlap the CT; label voxels beyond the CT's active box are counted.
    if (reference) summary.voxelsOutsideReference = voxelsOutsideReference(*label, g, *xf, *reference, mask.name());
    const std::optional<Coord> offset = latticeOffset(g, *xf);
    summary.resampled = !offset;
    reportProgress(progress, 0.25, "mask on the output grid");
    FloatTree::Ptr indicator = indicatorOnGrid(*label, g, *xf, offset);
    double maskVolumeMl =
        double(summary.labelVoxels) * g.spacingMm.x * g.spacingMm.y * g.spacingMm.z / 1000.0;
    label.reset();

    // The rectal tube: a thin, straight tube leaving the lumen's lowest end downwards, to the
    // image's edge or as the mask's lowest point. Its voxels become outside voxels.
    reportProgress(progress, 0.3, "rectal tube");
    RectalTube tube = cutMaskRectalTube(*indicator, g, *xf);
    if (tube.found) maskVolumeMl = std::max(0.0, maskVolumeMl - tube.volumeMl);

    // f0 = 0.5 - indicator: its linear zero crossing lies halfway between inside and outside
    // centres, where a binary mask's surface is. The region covers the exterior band, the
    // smoothing's reach and the constant offset below.
    const double maxSpacing = std::max({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z});
    const double sigmaMm = params.maskSmoothingVoxels * maxSpacing;
    const int iterations = int(std::ceil(3.0 * sigmaMm * sigmaMm / (h * h)));
    const int shellVoxels = params.bandVoxels + 3;
    FloatTree::Ptr f = initialField(*indicator, shellVoxels);
    FloatGrid::Ptr fGrid = FloatGrid::create(f);
    fGrid->setTransform(xf->copy());
    reportProgress(progress, 0.35, "mask level set");
    // Smooth within reach of the surface only: beyond 2 sigma + a voxel nothing moves.
    const float reachMm = static_cast<float>(2.0 * sigmaMm + h);
    // With smoothing, this first distance is read within reach + 1 voxel of the surface only:
    // the voxels deeper inside than reach + 3 voxels (every voxel within that many steps is
    // inside) are left out of its sweep (deactivated, their value kept, so that no false
    // interface appears at the edge). Fast sweeping's upwind values come from voxels nearer
    // the surface, so the distances within the band are those of a sweep over the whole
    // region; the final sweep below covers the whole region again.
    auto deep = std::make_shared<BoolTree>(false);
    if (iterations > 0) deep = leaveOutDeepVoxels(*f, reachMm, h);
    reportProgress(progress, 0.4, "mask level set: distance near the surface");
    FloatGrid::Ptr phi = detail::redistance(*fGrid);

    const float marginMm = static_cast<float>(CONSTRAINT_MARGIN_VOXELS * h);
    if (iterations > 0)
        phi = smoothAndRedistance(phi->tree(), *fGrid, *deep, *indicator, iterations, reachMm, marginMm, progress);
    fGrid.reset();
    f.reset();
    reportProgress(progress, 0.75, "restore the mask's volume");

    // A constant offset (bisection, within one voxel) so that the sub-voxel volume enclosed by
    // the level set equals the mask's voxel-count volume (no shrinking, no growing), with the
    // constraints applied after it, so that no mask centre changes side.
    const double targetVoxels = maskVolumeMl / voxelMl;
    restoreVolume(phi->tree(), *indicator, targetVoxels, h, marginMm);
    indicator.reset();
    phi->setTransform(xf->copy());
    reportProgress(progress, 0.9, "trim band and build mask");

    LumenSegmentation result;
    result.rectalTube = tube;
    detail::finishLumen(phi, params, result, progress);
    if (summaryOut) *summaryOut = summary;
    reportProgress(progress, 1.0, "lumen from mask");
    return result;
}

LumenSegmentation segmentFromMask(const Image3<float>& mask, const SegmentParams& params,
                                  const FloatGrid* reference, Progress* progress, MaskSummary* summary)
{
    MemoryImageSource source(mask, "mask image");
    return segmentFromMask(source, params, reference, progress, summary);
}

void checkPlausibleColon(const LumenSegmentation& seg, const SegmentParams& params, const std::string& name)
{
    double bigMl = 0, largestMl = 0;
    for (const LumenPiece& p : seg.pieces) {
        if (p.volumeMl >= params.minComponentMl) bigMl += p.volumeMl;
        largestMl = std::max(largestMl, p.volumeMl);
    }
    float deepest = 0;
    for (auto it = seg.sdf->tree().cbeginValueOn(); it; ++it) deepest = std::min(deepest, *it);
    const double ballMl = 4.0 / 3.0 * PI * std::pow(double(-deepest), 3) / 1000.0;
    const double elongation = ballMl > 0 ? bigMl / ballMl : 0.0;
    if (bigMl > 0 && elongation >= PLAUSIBLE_ELONGATION) return;
    std::ostringstream msg;
    msg << std::fixed << std::setprecision(1) << name
        << ": no plausible colon in the mask (a colon has pieces of at least " << params.minComponentMl
        << " mL whose volume is at least " << PLAUSIBLE_ELONGATION
        << " times that of the largest ball inside them: a tube, not a ball): ";
    if (seg.pieces.empty()) msg << "the lumen is empty";
    else if (bigMl == 0)
        msg << seg.pieces.size() << " piece(s), the largest " << std::setprecision(2) << largestMl << " mL";
    else
        msg << "the pieces of " << bigMl << " mL are compact, not a tube (largest inside ball " << std::setprecision(1)
            << 2.0 * double(-deepest) << " mm wide, " << ballMl << " mL; ratio " << std::setprecision(2) << elongation
            << ")";
    throw InputError(msg.str());
}

Image3<uint8_t> rasterizeLumen(const FloatGrid& sdf, const ImageGeometry& geometry)
{
    Image3<uint8_t> out;
    out.geometry = geometry;
    out.voxels.assign(static_cast<std::size_t>(geometry.voxelCount()), 0);
    const openvdb::CoordBBox active = sdf.evalActiveVoxelBoundingBox();
    if (active.empty()) return out;
    // The image's index box that can reach the level set's active box (its 8 corners mapped).
    std::array<int64_t, 3> lo{geometry.size[0], geometry.size[1], geometry.size[2]}, hi{-1, -1, -1};
    for (int corner = 0; corner < 8; ++corner) {
        const openvdb::Vec3d c((corner & 1) ? active.max().x() + 1.0 : active.min().x() - 1.0,
                               (corner & 2) ? active.max().y() + 1.0 : active.min().y() - 1.0,
                               (corner & 4) ? active.max().z() + 1.0 : active.min().z() - 1.0);
        const Vec3d u = geometry.indexFromWorld(fromVdb(sdf.transform().indexToWorld(c)));
        for (int a = 0; a < 3; ++a) {
            lo[std::size_t(a)] = std::min(lo[std::size_t(a)], int64_t(std::floor(u[a])));
            hi[std::size_t(a)] = std::max(hi[std::size_t(a)], int64_t(std::ceil(u[a])));
        }
    }
    for (int a = 0; a < 3; ++a) {
        lo[std::size_t(a)] = std::max<int64_t>(lo[std::size_t(a)], 0);
        hi[std::size_t(a)] = std::min<int64_t>(hi[std::size_t(a)], geometry.size[std::size_t(a)] - 1);
    }
    if (lo[0] > hi[0] || lo[1] > hi[1] || lo[2] > hi[2]) return out;
    tbb::parallel_for(tbb::blocked_range<int64_t>(lo[2], hi[2] + 1), [&](const tbb::blocked_range<int64_t>& r) {
        const openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler>
            sampler(sdf.getConstAccessor(), sdf.transform());
        for (int64_t k = r.begin(); k != r.end(); ++k)
            for (int64_t j = lo[1]; j <= hi[1]; ++j)
                for (int64_t i = lo[0]; i <= hi[0]; ++i) {
                    const Vec3d w = geometry.worldFromIndex({double(i), double(j), double(k)});
                    if (sampler.wsSample(toVdb(w)) < 0.0f) out.at(i, j, k) = 1;
                }
    });
    return out;
}

} // namespace flyover
