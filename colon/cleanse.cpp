// Electronic cleansing: tagged fluid under air-fluid levels (see cleanse.h for the rules).
// Per-leaf partial results are merged serially in leaf order, so that the outcome does not
// depend on the thread count.
#include "colon/cleanse.h"

#include "volume/mask_components.h"
#include "volume/segment_tools.h"

#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace flyover::detail {

namespace {

using openvdb::BoolTree;
using openvdb::Coord;
using openvdb::FloatTree;
using BoolLeaf = BoolTree::LeafNodeType;
using FloatLeaf = FloatTree::LeafNodeType;
using BoolConstAccessor = openvdb::tree::ValueAccessor<const BoolTree>;
using FloatConstAccessor = openvdb::tree::ValueAccessor<const FloatTree>;

const Coord FACE_STEPS[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};

inline Coord scaled(const Coord& step, int n) { return Coord(step.x() * n, step.y() * n, step.z() * n); }

/// The active voxels of `hu` above `thresholdHu` within `near` (leaf by leaf, in parallel).
BoolTree::Ptr candidatesWithin(const FloatTree& hu, const BoolTree& near, float thresholdHu)
{
    auto out = std::make_shared<BoolTree>(near);
    out->voxelizeActiveTiles();
    openvdb::tree::LeafManager<BoolTree> leaves(*out);
    leaves.foreach([&](BoolLeaf& leaf, std::size_t) {
        FloatConstAccessor huAcc(hu);
        for (auto it = leaf.beginValueOn(); it; ++it) {
            float v;
            if (!huAcc.probeValue(it.getCoord(), v) || !(v > thresholdHu)) leaf.setValueOff(it.pos(), false);
        }
    });
    pruneInactive(*out);
    return out;
}

/// The face-connected components of the candidates (active voxels of `hu` above `thresholdHu`)
/// that hold a voxel of `seeds`: a flood fill from the seeds through the candidates. Only
/// these components can touch the colon air's reach; the others (most of the skeleton) are
/// never visited.
BoolTree::Ptr candidatesConnectedTo(const FloatTree& hu, const BoolTree& seeds, float thresholdHu)
{
    auto reached = std::make_shared<BoolTree>(seeds);
    openvdb::tree::ValueAccessor<BoolTree> reachedAcc(*reached);
    FloatConstAccessor huAcc(hu);
    std::vector<Coord> stack;
    for (auto it = seeds.cbeginValueOn(); it; ++it) {
        stack.push_back(it.getCoord());
        while (!stack.empty()) {
            const Coord c = stack.back();
            stack.pop_back();
            for (const Coord& d : FACE_STEPS) {
                const Coord q = c + d;
                if (reachedAcc.isValueOn(q)) continue;
                float v;
                if (!huAcc.probeValue(q, v) || !(v > thresholdHu)) continue;
                reachedAcc.setValueOn(q, true);
                stack.push_back(q);
            }
        }
    }
    return reached;
}

/// True when one of the LEVEL_REACH_VOXELS voxels above `ijk` (against `down`) is air.
inline bool hasAirAbove(BoolConstAccessor& air, const Coord& ijk, const Coord& down)
{
    for (int a = 1; a <= LEVEL_REACH_VOXELS; ++a)
        if (air.isValueOn(ijk - scaled(down, a))) return true;
    return false;
}

/// Number of voxels of `fluid` with air above them, for each of the six directions.
std::array<std::uint64_t, 6> countLevelsPerDirection(const BoolTree& fluid, const BoolTree& air)
{
    openvdb::tree::LeafManager<const BoolTree> leaves(fluid);
    std::vector<std::array<std::uint64_t, 6>> perLeaf(leaves.leafCount());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.leafCount(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        BoolConstAccessor airAcc(air);
        for (std::size_t n = r.begin(); n != r.end(); ++n) {
            std::array<std::uint64_t, 6> c{};
            for (auto it = leaves.leaf(n).cbeginValueOn(); it; ++it)
                for (int d = 0; d < 6; ++d) c[d] += hasAirAbove(airAcc, it.getCoord(), FACE_STEPS[d]);
            perLeaf[n] = c;
        }
    });
    std::array<std::uint64_t, 6> total{};
    for (const auto& c : perLeaf)
        for (int d = 0; d < 6; ++d) total[d] += c[d];
    return total;
}

/// What one fluid component looks like from the air above it.
struct PoolStats {
    std::uint64_t voxels = 0, interior = 0;
    double sumHu = 0, sumInteriorHu = 0;
    std::uint64_t nearAir = 0;       ///< voxels within the dilated air
    std::uint64_t level = 0;         ///< of those, voxels with air above them along g
    std::uint64_t tops = 0;          ///< level voxels whose upper neighbour is not fluid
    double sumTopHeight = 0, sumTopHeight2 = 0;  ///< height along g (index units)
    openvdb::Vec3d minWorld{std::numeric_limits<double>::max()};
    openvdb::Vec3d maxWorld{-std::numeric_limits<double>::max()};

    void add(const PoolStats& o)
    {
        voxels += o.voxels;
        interior += o.interior;
        sumHu += o.sumHu;
        sumInteriorHu += o.sumInteriorHu;
        nearAir += o.nearAir;
        level += o.level;
        tops += o.tops;
        sumTopHeight += o.sumTopHeight;
        sumTopHeight2 += o.sumTopHeight2;
        minWorld = openvdb::math::minComponent(minWorld, o.minWorld);
        maxWorld = openvdb::math::maxComponent(maxWorld, o.maxWorld);
    }
};

PoolStats measurePool(const BoolTree& pool, const BoolTree& near, const BoolTree& air,
                      const FloatTree& hu, const openvdb::math::Transform& xf, const Coord& down)
{
    const bool haveGravity = down != Coord(0, 0, 0);
    openvdb::tree::LeafManager<const BoolTree> leaves(pool);
    std::vector<PoolStats> perLeaf(leaves.leafCount());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.leafCount(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        BoolConstAccessor poolAcc(pool), nearAcc(near), airAcc(air);
        FloatConstAccessor huAcc(hu);
        for (std::size_t n = r.begin(); n != r.end(); ++n) {
            PoolStats& s = perLeaf[n];
            for (auto it = leaves.leaf(n).cbeginValueOn(); it; ++it) {
                const Coord ijk = it.getCoord();
                const double v = huAcc.getValue(ijk);
                ++s.voxels;
                s.sumHu += v;
                bool interior = true;
                for (const Coord& d : FACE_STEPS) interior = interior && poolAcc.isValueOn(ijk + d);
                if (interior) {
                    ++s.interior;
                    s.sumInteriorHu += v;
                }
                const openvdb::Vec3d w = xf.indexToWorld(ijk);
                s.minWorld = openvdb::math::minComponent(s.minWorld, w);
                s.maxWorld = openvdb::math::maxComponent(s.maxWorld, w);
                if (!nearAcc.isValueOn(ijk)) continue;
                ++s.nearAir;
                if (!haveGravity || !hasAirAbove(airAcc, ijk, down)) continue;
                ++s.level;
                if (poolAcc.isValueOn(ijk - down)) continue;
                const double height = double(ijk.x()) * down.x() + double(ijk.y()) * down.y() +
                                      double(ijk.z()) * down.z();
                ++s.tops;
                s.sumTopHeight += height;
                s.sumTopHeight2 += height * height;
            }
        }
    });
    PoolStats total;
    for (const PoolStats& s : perLeaf) total.add(s);
    return total;
}

/// The top voxels of `pool` with air above them along g, and the voxels in between.
void addRim(const BoolTree& pool, const BoolTree& air, const Coord& down, BoolTree& rim)
{
    openvdb::tree::LeafManager<const BoolTree> leaves(pool);
    std::vector<std::vector<Coord>> perLeaf(leaves.leafCount());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.leafCount(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        BoolConstAccessor poolAcc(pool), airAcc(air);
        for (std::size_t n = r.begin(); n != r.end(); ++n)
            for (auto it = leaves.leaf(n).cbeginValueOn(); it; ++it) {
                const Coord top = it.getCoord();
                if (poolAcc.isValueOn(top - down)) continue;
                for (int a = 1; a <= LEVEL_REACH_VOXELS; ++a) {
                    const Coord u = top - scaled(down, a);
                    if (poolAcc.isValueOn(u)) break;
                    if (airAcc.isValueOn(u)) {
                        // The top voxel too: above the threshold, yet partly air, its HU can sit
                        // below the fluid's surface value and would read as wall.
                        for (int b = 0; b < a; ++b) perLeaf[n].push_back(top - scaled(down, b));
                        break;
                    }
                }
            }
    });
    openvdb::tree::ValueAccessor<BoolTree> rimAcc(rim);
    for (const auto& coords : perLeaf)
        for (const Coord& c : coords) rimAcc.setValueOn(c, true);
}

} // namespace

TaggedFluid findTaggedFluid(const openvdb::FloatGrid& hu, const BoolTree& colonAir,
                            const SegmentParams& params)
{
    TaggedFluid out;
    out.joined = std::make_shared<BoolTree>(false);
    out.rim = std::make_shared<BoolTree>(false);
    out.rejected = std::make_shared<BoolTree>(false);
    const FloatTree& huTree = hu.tree();
    const openvdb::math::Transform& xf = hu.transform();
    const double voxelMl = std::abs(xf.voxelVolume()) / 1000.0;

    // Fluid under an air-fluid level lies within the partial-volume reach of the air: only the
    // candidate components with a voxel there matter, so only they are found (a flood fill from
    // the candidates near the air), not every voxel above the threshold (bone).
    const float threshold = static_cast<float>(params.fluidThresholdHu);
    BoolTree near(colonAir);
    dilateVoxels(near, LEVEL_REACH_VOXELS, Neighbours::All);
    const BoolTree::Ptr nearCandidatesPtr = candidatesWithin(huTree, near, threshold);
    const BoolTree& nearCandidates = *nearCandidatesPtr;
    if (nearCandidates.activeVoxelCount() == 0) return out;
    const BoolTree::Ptr candidates = candidatesConnectedTo(huTree, nearCandidates, threshold);

    // Gravity: the direction along which most fluid near the air has that air above it.
    const auto counts = countLevelsPerDirection(nearCandidates, colonAir);
    const int best = int(std::max_element(counts.begin(), counts.end()) - counts.begin());
    if (counts[std::size_t(best)] >= std::uint64_t(MIN_LEVEL_VOXELS)) {
        out.gravityStep = FACE_STEPS[best];
        const openvdb::Vec3d g =
            xf.indexToWorld(out.gravityStep.asVec3d()) - xf.indexToWorld(openvdb::Vec3d(0.0));
        out.gravityDirection = normalize(Vec3d{g[0], g[1], g[2]});
    }
    const Coord down = out.gravityStep;

    std::vector<BoolTree::Ptr> joinedTrees, rejectedTrees;
    std::vector<FluidPool> joinedPools, rejectedPools;
    for (const BoolTree::Ptr& component : connectedComponents(*candidates)) {
        BoolTree touching(*component);
        touching.topologyIntersection(near);
        // Far from the colon air: bone, vessels, organs. (Not empty(): an intersection keeps
        // nodes without active voxels.)
        if (touching.activeVoxelCount() == 0) continue;
        const PoolStats s = measurePool(*component, near, colonAir, huTree, xf, down);
        FluidPool pool;
        pool.volumeMl = double(s.voxels) * voxelMl;
        pool.meanHu = s.interior > 0 ? s.sumInteriorHu / double(s.interior)
                                     : s.sumHu / double(std::max<std::uint64_t>(s.voxels, 1));
        pool.surfaceHu = 0.5 * (pool.meanHu + params.wallHu);
        pool.minMm = {s.minWorld[0], s.minWorld[1], s.minWorld[2]};
        pool.maxMm = {s.maxWorld[0], s.maxWorld[1], s.maxWorld[2]};
        double spread = std::numeric_limits<double>::infinity();
        if (s.tops > 0) {
            const double mean = s.sumTopHeight / double(s.tops);
            spread = std::sqrt(std::max(0.0, s.sumTopHeight2 / double(s.tops) - mean * mean));
            // The level lies half a voxel above the top voxel centres, on average.
            const openvdb::Vec3d levelWorld = xf.indexToWorld((mean - 0.5) * down.asVec3d());
            pool.levelMm = dot(Vec3d{levelWorld[0], levelWorld[1], levelWorld[2]}, out.gravityDirection);
        }
        const bool underLevel = s.level >= std::max<std::uint64_t>(MIN_LEVEL_VOXELS, s.nearAir / 2) &&
                                spread <= MAX_LEVEL_SPREAD_VOXELS;
        if (!params.cleanse) pool.reason = "cleanse off";
        else if (!underLevel) pool.reason = "no level below air";
        else {
            pool.joined = true;
            pool.reason = "air-fluid level";
        }
        (pool.joined ? joinedPools : rejectedPools).push_back(pool);
        (pool.joined ? joinedTrees : rejectedTrees).push_back(component);
    }

    for (std::size_t i = 0; i < joinedTrees.size(); ++i) {
        out.joined->topologyUnion(*joinedTrees[i]);
        addRim(*joinedTrees[i], colonAir, down, *out.rim);
    }
    for (const BoolTree::Ptr& t : rejectedTrees) out.rejected->topologyUnion(*t);
    out.poolTrees = std::move(joinedTrees);
    out.pools = std::move(joinedPools);
    out.pools.insert(out.pools.end(), rejectedPools.begin(), rejectedPools.end());
    return out;
}

} // namespace flyover::detail
