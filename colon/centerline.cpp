// Centerline on the sparse lumen grid (see centerline.h for the method in brief):
//  1. flat leaf-blocked index of the lumen voxels (sdf < 0), D = -sdf;
//  2. 26-connected pieces by breadth-first search (lumen_waves.h); the last voxels a search reaches are
//     farthest from its seed in steps, so the labelling pass also yields one geodesic
//     farthest end per piece, and a second search from it yields the other end;
//  3. per piece, a minimal path under the cost D^-p per unit length (route_search.h: bucket
//     queues; the core's and the whole piece's searched from both ends at once)
//     through the piece's core (voxels at least half as deep as the deepest nearby), which
//     is all a path through the middle needs and a quarter of the voxels;
//  4. per piece: end trimming, ridge of D, cross-section centroids, twiced Gaussian
//     smoothing, straight extension into the blind ends;
//  5. pieces ordered and bridged (centerline_bridge.h), uniform resampling, radii, frames.
// Searches are deterministic (the two ends of a route search run side by side, each serial);
// per-point geometry runs in parallel over points.
#include "colon/centerline.h"

#include "colon/centerline_bridge.h"
#include "colon/centerline_path.h"
#include "colon/centerline_far_end.h"
#include "volume/error.h"
#include "colon/lumen_index.h"
#include "colon/lumen_waves.h"
#include "colon/route_search.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

namespace flyover {

namespace {

using namespace lumen_index;
using route_search::RouteWorkspace;
using route_search::shortestRoute;
using namespace centerline_path;

/// 26-connected lumen pieces: a label per slot, and per piece its voxel count and a voxel its
/// breadth-first labelling search reached last (the lowest slot of those farthest in steps from
/// the seed: for a tube, at one of its two ends).
struct Pieces {
    std::vector<std::int32_t> label;  ///< per slot, -1 for non-lumen
    std::vector<std::size_t> size;    ///< per label
    std::vector<Slot> lastReached;    ///< per label
};

Pieces labelPieces(const LumenIndex& index, const SlotBits& holes, Progress* progress)
{
    Pieces c;
    c.label.assign(index.slotCount(), -1);
    SlotBits labelled = holes;  // and the lumen voxels labelled
    LumenWaves waves(index);
    std::vector<Slot> seed(1);
    for (std::size_t b = 0; b < index.blockOrigin.size(); ++b)
        for (int x = 0; x < LEAF_VOXELS / 64; ++x)
            for (std::uint64_t clear; (clear = ~labelled.blockWords(b)[x]) != 0;) {
                seed[0] = static_cast<Slot>(b * LEAF_VOXELS) + static_cast<Slot>(x * 64 + __builtin_ctzll(clear));
                const std::int32_t id = static_cast<std::int32_t>(c.size.size());
                std::size_t count = 0;
                const WaveEnd end = waves.run(labelled, seed, [&](std::int32_t, std::uint32_t block, const BlockWords& w) {
                    forEachSlot(block, w, [&](Slot s) {
                        c.label[s] = id;
                        ++count;
                    });
                }, progress);
                c.size.push_back(count);
                c.lastReached.push_back(end.lowestInLast);
            }
    return c;
}

/// Breadth-first search from the distinct `seeds` (the queue's start) over their pieces, at most
/// `maxSteps` 26-neighbour steps deep: calls reach(slot, steps) for each slot reached, seeds
/// with 0, and leaves the slots in the order reached in `queue`. `holes`: holeBits(index).
template<typename Reach>
void breadthFirst(const LumenIndex& index, const SlotBits& holes, std::vector<Slot>& queue, std::int32_t maxSteps,
                  Reach&& reach, Progress* progress)
{
    SlotBits reached = holes;  // a bit per slot: a copy is a few MB at most
    std::size_t kept = 0;
    for (Slot s : queue)
        if (!reached.testAndSet(s)) queue[kept++] = s;
    queue.resize(kept);
    for (Slot s : queue) reach(s, 0);
    std::size_t layerEnd = queue.size();
    std::int32_t layer = 0;
    for (std::size_t head = 0; head < queue.size(); ++head) {
        if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
        if (head == layerEnd) {
            if (++layer == maxSteps) break;
            layerEnd = queue.size();
        }
        const std::int32_t next = layer + 1;
        forEachClearNeighbour(index, reached, queue[head], [&](Slot t) {
            reached.set(t);
            reach(t, next);
            queue.push_back(t);
        });
    }
}

/// Breadth-first search from `source` over its piece: steps[s] = number of 26-neighbour steps
/// from the source (slots of this piece only; others untouched). `holes`: holeBits(index).
/// Returns the lowest slot of those farthest in steps.
Slot stepsFrom(const LumenIndex& index, const SlotBits& holes, Slot source, std::vector<std::int32_t>& steps,
               Progress* progress)
{
    SlotBits reached = holes;
    LumenWaves waves(index);
    const WaveEnd end = waves.run(reached, {source}, [&](std::int32_t layer, std::uint32_t block, const BlockWords& w) {
        forEachSlot(block, w, [&](Slot s) { steps[s] = layer; });
    }, progress);
    return end.lowestInLast;
}

void validate(const openvdb::FloatGrid& sdf, const CenterlineParams& p)
{
    auto bad = [](const std::string& what) { throw ParameterError("CenterlineParams." + what); };
    if (!(p.stepMm > 0) || !std::isfinite(p.stepMm)) bad("stepMm must be finite and > 0");
    if (!(p.wallPenalty >= 0) || !std::isfinite(p.wallPenalty))
        bad("wallPenalty must be finite and >= 0");
    if (!(p.smoothingMm >= 0) || !std::isfinite(p.smoothingMm))
        bad("smoothingMm must be finite and >= 0");
    if (p.rectumMm && !(std::isfinite(p.rectumMm->x) && std::isfinite(p.rectumMm->y) &&
                        std::isfinite(p.rectumMm->z)))
        bad("rectumMm must be a finite point");
    if (!(p.minPieceMl >= 0) || !std::isfinite(p.minPieceMl)) bad("minPieceMl must be finite and >= 0");
    if (!(p.minPieceFraction >= 0 && p.minPieceFraction <= 1)) bad("minPieceFraction must be in [0, 1]");
    if (!(p.bridgeTurnMmPerRad >= 0) || !std::isfinite(p.bridgeTurnMmPerRad))
        bad("bridgeTurnMmPerRad must be finite and >= 0");
    if (!(p.nearWallMm >= 0) || !std::isfinite(p.nearWallMm)) bad("nearWallMm must be finite and >= 0");
    if (!(p.corridorMm >= 0) || !std::isfinite(p.corridorMm)) bad("corridorMm must be finite and >= 0");
    const auto& xf = sdf.transform();
    if (!xf.isLinear()) throw InputError("extractCenterline: the sdf grid's transform is not linear");
    const openvdb::Vec3d vs = xf.voxelSize();
    if (!(vs[0] > 0) || std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] ||
        std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
        throw InputError("extractCenterline: the sdf grid's voxels are not cubic");
}

/// The end of the tube nearest to `seed` (the lowest lumen voxel, or the lumen voxel nearest to
/// a --rectum-mm hint), for a piece traced again from there. The end is a voxel farthest along
/// the lumen from the seed's farthest voxel F (the cecum): globally, when that lies within
/// END_REACH_MM (in steps) of the seed; else the farthest from F among the voxels within that
/// reach of the seed, when it lies inside the reach (a local end there: the seed's blind end,
/// such as a wide rectum whose cap holds the lowest voxel while the piece's other tips, a loop
/// left over by a contact cut or a branch, lie farther from F); else the global one (the seed
/// lies at no end: mid-tube). `steps` is overwritten.
Slot tubeEndNearSeed(const LumenIndex& index, const SlotBits& holes, Slot seed, std::vector<std::int32_t>& steps,
                     double voxelMm, Progress* progress)
{
    constexpr double END_REACH_MM = LOWEST_END_SLACK_MM;
    const std::int32_t reach = std::max<std::int32_t>(3, static_cast<std::int32_t>(END_REACH_MM / voxelMm));
    std::vector<Slot> near{seed};
    std::vector<std::int32_t> nearSteps;
    breadthFirst(index, holes, near, reach, [&](Slot, std::int32_t n) { nearSteps.push_back(n); }, progress);
    const Slot far = stepsFrom(index, holes, seed, steps, progress);
    const Slot globalEnd = stepsFrom(index, holes, far, steps, progress);
    Slot local = seed;
    std::int32_t localSteps = 0;
    bool globalNear = false;
    for (std::size_t i = 0; i < near.size(); ++i) {
        if (near[i] == globalEnd) globalNear = true;
        if (steps[near[i]] > steps[local]) {
            local = near[i];
            localSteps = nearSteps[i];
        }
    }
    if (globalNear) return globalEnd;
    // Inside the reach by a margin: a local maximum of the steps from F, not the reach's rim.
    return localSteps + 2 < reach ? local : globalEnd;
}

/// A thin tube at the back end of an evenly sampled path (every fineMm): the last sample at least
/// APPENDIX_DEPTH_FRACTION as deep as the deepest sample of the path's last 150 mm (the mouth),
/// when the stretch beyond it is at least 10 mm long and nowhere deeper than that fraction.
struct ThinEnd {
    std::size_t index = 0;
    double lengthMm = 0, thinDepthMm = 0, wideDepthMm = 0;
};
std::optional<ThinEnd> thinFarEnd(const std::vector<Vec3d>& pts, DepthProbe& depthAt, double fineMm)
{
    constexpr double WINDOW_MM = 150.0, MIN_LENGTH_MM = 10.0;
    const long n = static_cast<long>(pts.size());
    const long window = std::min(n, static_cast<long>(WINDOW_MM / fineMm));
    if (n < 3 || window < 3) return std::nullopt;
    std::vector<double> d(static_cast<std::size_t>(window));
    for (long k = 0; k < window; ++k) d[std::size_t(k)] = depthAt(pts[std::size_t(n - window + k)]);
    const double wide = *std::max_element(d.begin(), d.end());
    const double bound = APPENDIX_DEPTH_FRACTION * wide;
    long m = window - 1;
    while (m > 0 && d[std::size_t(m)] < bound) --m;
    const double lengthMm = double(window - 1 - m) * fineMm;
    if (m == 0 || lengthMm < MIN_LENGTH_MM) return std::nullopt;
    ThinEnd t;
    t.index = std::size_t(n - window + m);
    t.lengthMm = lengthMm;
    t.thinDepthMm = *std::max_element(d.begin() + m + 1, d.end());
    t.wideDepthMm = wide;
    return t;
}

/// One piece's centerline and where it came from.
struct PiecePath {
    std::int32_t label = -1;
    std::vector<Vec3d> pointsMm;
    const char* searchedOn = "";  ///< CenterlinePieceInfo::routeSearchedOn
};

PieceEnds endsOf(const std::vector<Vec3d>& p, double voxelMm)
{
    return {p.front(), p.back(), frontOutward(p, voxelMm), backOutward(p, voxelMm)};
}

/// Step 2's pieces that the path takes: the largest and those large enough beside it, largest
/// first (ties: lower label, i.e. first in slot order); `bySize` is every piece in that order.
struct UsedPieces {
    std::vector<std::int32_t> bySize, used;
};

UsedPieces usedPieces(const Pieces& pieces, double voxelMl, const CenterlineParams& params)
{
    UsedPieces u;
    u.bySize.resize(pieces.size.size());
    for (std::size_t i = 0; i < u.bySize.size(); ++i) u.bySize[i] = static_cast<std::int32_t>(i);
    std::stable_sort(u.bySize.begin(), u.bySize.end(),
                     [&](std::int32_t a, std::int32_t b) { return pieces.size[a] > pieces.size[b]; });
    for (std::size_t r = 0; r < u.bySize.size(); ++r)
        if (r == 0 ||
            pieceLargeEnough(double(pieces.size[u.bySize[r]]), double(pieces.size[u.bySize[0]]), voxelMl, params))
            u.used.push_back(u.bySize[r]);
    return u;
}

/// The lowest lumen voxel of the pieces used and, with rectumMm, the lumen voxel nearest to it
/// (the seed): its piece's path runs from the end of the tube nearest to the seed to the voxel
/// farthest from that end along the lumen (the cecum). Without rectumMm each piece runs between
/// its farthest pair, and the lowest end in world z is the rectum (step 4).
struct RectumSeeds {
    Slot rectumSeed = NO_SLOT, lowestSlot = NO_SLOT;
};

RectumSeeds rectumSeeds(const LumenIndex& index, const openvdb::math::Transform& xf, const Pieces& pieces,
                        const std::vector<std::int32_t>& used, const CenterlineParams& params)
{
    RectumSeeds r;
    std::vector<std::uint8_t> isUsed(pieces.size.size(), 0);
    for (std::int32_t l : used) isUsed[l] = 1;
    double best = std::numeric_limits<double>::infinity(), lowest = best;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        if (!index.isLumen(s) || !isUsed[pieces.label[s]]) continue;
        const Vec3d w = toVec(xf.indexToWorld(index.coord(s)));
        if (w.z < lowest) {
            lowest = w.z;
            r.lowestSlot = s;
        }
        if (params.rectumMm && distance(w, *params.rectumMm) < best) {
            best = distance(w, *params.rectumMm);
            r.rectumSeed = s;
        }
    }
    return r;
}

/// Step 3: per piece, ends, the minimal path through the core, refinement. A step of length l
/// between voxels u and v costs l * (w(u) + w(v)) / 2 with w = max(D, eps)^-p: the trapezoid
/// rule for the integral of D^-p along the step, symmetric in u and v (the same path either
/// way). Near the wall D is small and the cost explodes, so the path keeps to the ridge of D,
/// the medial axis; on a bend the ridge stays optimal because any sideways shift lowers D
/// linearly while it shortens the path only at second order. eps = half a voxel: the distance
/// is not resolved below that, and it bounds the cost of voxels at the wall.
class PieceTracer {
public:
    PieceTracer(const LumenIndex& index, const SlotBits& holes, const Pieces& pieces, const openvdb::FloatGrid& grid,
                const CenterlineParams& params, double fineMm, Progress* progress);

    /// One piece's path; from the end of the tube nearest to `seed` when one is given. `from`:
    /// start there instead (with `plugged`, the piece's holes plus voxels that end the search
    /// there: the far end is then the farthest voxel reached without crossing them).
    PiecePath trace(std::int32_t label, Slot seed, Slot from = NO_SLOT, const SlotBits* plugged = nullptr);

    /// No voxel of the piece reached yet (before a search that must not find ends left over
    /// from an earlier one: one that stops at a plug).
    void unreached(std::int32_t label);

    /// stepsFrom over `holes` into the tracer's steps; steps() reads them.
    Slot stepsFrom(const SlotBits& holes, Slot source)
    {
        return flyover::stepsFrom(mIndex, holes, source, mSteps, mProgress);
    }
    const std::vector<std::int32_t>& steps() const { return mSteps; }

private:
    double medial(Slot u, Slot v, int k) const
    {
        return mStepMm[k] * 0.5 * (double(mWeight[u]) + double(mWeight[v]));
    }
    /// A two-voxel step, taken only where the inscribed balls of its ends overlap.
    double medialCoarse(Slot u, Slot v, int k) const
    {
        const double len = 2.0 * mStepMm[k];
        if (!(double(mIndex.depthMm[u]) + double(mIndex.depthMm[v]) > len))
            return std::numeric_limits<double>::infinity();
        return len * 0.5 * (double(mWeight[u]) + double(mWeight[v]));
    }
    /// A two-voxel step through the voxel between, at the two steps' cost.
    double medialThrough(Slot u, Slot v, int k) const
    {
        const Slot m = mIndex.stepSlot(u, k);
        if (m == NO_SLOT || !mIndex.isLumen(m)) return std::numeric_limits<double>::infinity();
        return medial(u, m, k) + medial(m, v, k);
    }
    static bool isEven(Slot s)
    {
        const int off = static_cast<int>(s % LEAF_VOXELS);
        return (off & ((1 << (2 * LEAF_LOG2)) | (1 << LEAF_LOG2) | 1)) == 0;
    }
    bool searchCorridors(Slot a, Slot b, std::vector<Slot>& route);

    const LumenIndex& mIndex;
    const SlotBits& mHoles;
    const Pieces& mPieces;
    const openvdb::FloatGrid& mGrid;
    const CenterlineParams& mParams;
    const double mVoxelMm, mFineMm;
    Progress* mProgress;
    std::vector<float> mWeight;
    std::vector<std::uint8_t> mCore, mCoarse;
    std::array<double, 26> mStepMm{};
    double mMinEdge = 0, mMaxEdge = 0;
    std::vector<std::int32_t> mSteps;
    std::vector<Slot> mPieceSlots;
    RouteWorkspace mRouteWork;
};

PieceTracer::PieceTracer(const LumenIndex& index, const SlotBits& holes, const Pieces& pieces,
                         const openvdb::FloatGrid& grid, const CenterlineParams& params, double fineMm,
                         Progress* progress)
    : mIndex(index), mHoles(holes), mPieces(pieces), mGrid(grid), mParams(params),
      mVoxelMm(grid.transform().voxelSize()[0]), mFineMm(fineMm), mProgress(progress),
      mWeight(index.slotCount(), 0.0f), mCore(index.slotCount(), 0), mCoarse(index.slotCount(), 0),
      mSteps(index.slotCount(), -1)
{
    const double eps = 0.5 * mVoxelMm;
    // The core: voxels at least half as deep as the deepest voxel nearby (within one to two
    // leaves). The minimal path runs along the ridge of D, deep inside the core, so leaving out
    // the outer shell does not change it, while it quarters the search.
    const std::vector<float> nearby = nearbyMaxDepth(index);
    const float coreMarginMm = static_cast<float>(3.0 * mVoxelMm);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, index.slotCount(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t s = r.begin(); s != r.end(); ++s) {
            const float d = index.depthMm[s];
            if (d < 0.0f) continue;
            mWeight[s] = static_cast<float>(std::pow(std::max<double>(d, eps), -params.wallPenalty));
            const float m = nearby[s / LEAF_VOXELS];
            mCore[s] = d >= std::min(0.5f * m, m - coreMarginMm);
        }
    });
    float minWeight = std::numeric_limits<float>::max(), maxWeight = 0.0f;
    for (std::size_t s = 0; s < index.slotCount(); ++s)
        if (index.depthMm[s] >= 0.0f) {
            minWeight = std::min(minWeight, mWeight[s]);
            maxWeight = std::max(maxWeight, mWeight[s]);
        }
    for (int k = 0; k < 26; ++k) mStepMm[k] = STEPS[k].lengthVoxels * mVoxelMm;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, index.slotCount(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t s = r.begin(); s != r.end(); ++s)
            mCoarse[s] = mCore[s] && isEven(static_cast<Slot>(s));
    });
    mMinEdge = mVoxelMm * double(minWeight);
    mMaxEdge = std::sqrt(3.0) * mVoxelMm * double(maxWeight);
}

void PieceTracer::unreached(std::int32_t label)
{
    for (Slot s = 0; s < mIndex.slotCount(); ++s)
        if (mPieces.label[s] == label) mSteps[s] = -1;
}

// Where a narrowing splits a piece's core, the minimal route leaves the core only in the
// narrowing and at the piece's ends (the cap walls it starts and ends on). So the route is
// searched on the core plus corridors through those places: the piece's voxels within
// corridorMm (in steps, at least three) of where a route over the piece's voxels of even
// coordinates (an eighth of them; each two-voxel step through the voxel between, at the two
// steps' cost) runs outside the core, and of the two ends (the route over the core's voxels
// alone was found not to exist). False when that lattice's route does not exist either (a
// passage the lattice misses): the whole piece is then searched. On gca-colon-00020 (10.5 M
// voxels, the core split near the far end) the lattice's route adds 13.7 k voxels to the core,
// and the route found is the whole piece's, voxel for voxel. `mCore` and `mCoarse` are left as
// they were (a piece traced again from a seed searches its corridors again).
bool PieceTracer::searchCorridors(Slot a, Slot b, std::vector<Slot>& route)
{
    const auto through = [this](Slot u, Slot v, int k) { return medialThrough(u, v, k); };
    const auto step = [this](Slot u, Slot v, int k) { return medial(u, v, k); };
    Slot ends[2] = {NO_SLOT, NO_SLOT};
    std::vector<std::uint8_t>& even = mCoarse;  // the core's even voxels, restored below
    for (Slot s : mPieceSlots) {
        even[s] = isEven(s);
        if (!even[s] || mSteps[s] < 0) continue;
        if (ends[0] == NO_SLOT || mSteps[s] < mSteps[ends[0]]) ends[0] = s;
        if (ends[1] == NO_SLOT || mSteps[s] > mSteps[ends[1]]) ends[1] = s;
    }
    std::vector<Slot> lattice;
    const bool found = ends[0] != NO_SLOT && ends[0] != ends[1] &&
                       shortestRoute<2>(mIndex, even, ends[0], ends[1], through, 2.0 * mMinEdge, 2.0 * mMaxEdge,
                                        mRouteWork, lattice, mProgress);
    for (Slot s : mPieceSlots) even[s] = mCore[s] && isEven(s);
    if (!found) return false;
    std::vector<Slot> queue{a, b};
    for (std::size_t i = 0; i < lattice.size(); ++i) {
        const Slot r = lattice[i];
        if (!mCore[r]) queue.push_back(r);
        if (i + 1 == lattice.size()) break;
        const Coord d = mIndex.coord(lattice[i + 1]) - mIndex.coord(r);
        const Slot m = mIndex.stepSlot(r, lumen_index::stepIndex(d[0] / 2, d[1] / 2, d[2] / 2));
        if (m != NO_SLOT && !mCore[m]) queue.push_back(m);
    }
    // Breadth-first from those voxels, corridorMm / voxelMm steps deep and at least three (on the
    // small phantom's 2.5 mm voxels, two steps round a stricture gave another route than the
    // whole piece's near the cecum's cap).
    const int depthSteps = std::max(3, static_cast<int>(std::ceil(mParams.corridorMm / mVoxelMm)));
    breadthFirst(mIndex, mHoles, queue, depthSteps, [](Slot, std::int32_t) {}, mProgress);
    std::vector<Slot> added;
    for (Slot s : queue)
        if (!mCore[s]) {
            mCore[s] = 1;
            added.push_back(s);
        }
    const bool routed = shortestRoute<1>(mIndex, mCore, a, b, step, mMinEdge, mMaxEdge, mRouteWork, route, mProgress);
    for (Slot s : added) mCore[s] = 0;
    return routed;
}

PiecePath PieceTracer::trace(std::int32_t label, Slot seed, Slot from, const SlotBits* plugged)
{
    const auto step = [this](Slot u, Slot v, int k) { return medial(u, v, k); };
    const auto coarseStep = [this](Slot u, Slot v, int k) { return medialCoarse(u, v, k); };
    // Geodesic farthest ends: a search from the labelling's last voxel (one end) reaches the
    // other end last. Both lie on the wall of the blind ends; the path runs between the core
    // voxels nearest to them in steps.
    Slot a = mPieces.lastReached[label];
    if (from != NO_SLOT) {
        a = from;
    } else if (seed != NO_SLOT) {
        a = tubeEndNearSeed(mIndex, mHoles, seed, mSteps, mVoxelMm, mProgress);
    }
    if (plugged) unreached(label);  // voxels past the plug are not reached: no end may lie there
    const Slot b = stepsFrom(plugged ? *plugged : mHoles, a);
    // The search runs on the coarsest set that connects the ends: the core's voxels of even
    // coordinates (an eighth of them) joined by two-voxel steps, then the core, then the whole
    // piece (a stricture, or a piece next to a much deeper one, can break the core: on a 2.4 m
    // real colon, a narrowing 1.6 mm deep between stretches 10 mm deep). The path's precision
    // does not matter, the refinement moves it to the sections' centroids.
    Slot ends[2][2] = {{NO_SLOT, NO_SLOT}, {NO_SLOT, NO_SLOT}};  // [coarse, core][near, far]
    mPieceSlots.clear();
    for (Slot s = 0; s < mIndex.slotCount(); ++s) {
        if (mPieces.label[s] != label) continue;
        mPieceSlots.push_back(s);
        if (!mCore[s] || mSteps[s] < 0) continue;
        for (int level = 0; level < 2; ++level) {
            if (level == 0 && !isEven(s)) continue;
            Slot* e = ends[level];
            if (e[0] == NO_SLOT || mSteps[s] < mSteps[e[0]]) e[0] = s;
            if (e[1] == NO_SLOT || mSteps[s] > mSteps[e[1]]) e[1] = s;
        }
    }
    // The coarse lattice holds an eighth of the core: its search is short, from one end.
    const route_search::RouteOptions coarseSearch{false};
    std::vector<Slot> route;
    const bool coarseRoute = ends[0][0] != NO_SLOT && ends[0][0] != ends[0][1] &&
                             shortestRoute<2>(mIndex, mCoarse, ends[0][0], ends[0][1], coarseStep, 2.0 * mMinEdge,
                                              2.0 * mMaxEdge, mRouteWork, route, mProgress, coarseSearch);
    const bool coreRoute = coarseRoute || (ends[1][0] != NO_SLOT &&
                                           shortestRoute<1>(mIndex, mCore, ends[1][0], ends[1][1], step, mMinEdge,
                                                            mMaxEdge, mRouteWork, route, mProgress));
    const char* searchedOn = coarseRoute ? "coarse core" : "core";
    if (!coreRoute && mParams.corridorMm > 0 && searchCorridors(a, b, route)) {
        searchedOn = "core and corridors";
    } else if (!coreRoute) {
        for (Slot s : mPieceSlots) mCore[s] = 1;
        if (!shortestRoute<1>(mIndex, mCore, a, b, step, mMinEdge, mMaxEdge, mRouteWork, route, mProgress))
            route.assign(1, a);  // cannot happen: a and b lie in one piece
        searchedOn = "whole piece";
    }
    std::vector<Vec3d> raw;
    const openvdb::math::Transform& xf = mGrid.transform();
    for (Slot s : route) raw.push_back(toVec(xf.indexToWorld(mIndex.coord(s))));
    PiecePath path;
    path.label = label;
    path.pointsMm = refinePath(raw, mGrid, mVoxelMm, mFineMm, mParams);
    path.searchedOn = searchedOn;
    return path;
}

/// The traced pieces, their ends and the travel order being built (steps 4 to 5).
struct TracedPieces {
    std::vector<PiecePath> paths;
    std::vector<PieceEnds> ends;
    int first = 0;
    bool firstReversed = false;
    bool reseeded = false;

    void set(std::size_t i, PiecePath path, double voxelMm)
    {
        ends[i] = endsOf(path.pointsMm, voxelMm);
        paths[i] = std::move(path);
    }
};

/// Step 4: the rectum end, the lowest piece end in world z (LPS: +z is superior), or the end
/// nearest to rectumMm; its piece comes first, entered there. Every piece is first traced
/// between its own farthest pair, whatever the hint, so that the path from one end and the path
/// from the other are the same curve (a piece with cycles or branches has several tips, and the
/// tip farthest from the hint's end need not be the one the other direction starts from). Only
/// a hint that lies at none of these ends re-traces its piece from there; without a hint, so
/// does a lowest end far above the lowest lumen voxel (the farthest pair of its piece missed the
/// rectum: a shortcut left through an uncut contact, a branch).
void chooseRectumEnd(TracedPieces& t, PieceTracer& tracer, const LumenIndex& index, const Pieces& pieces,
                     const openvdb::math::Transform& xf, const RectumSeeds& seeds, DepthProbe& depthAt,
                     const CenterlineParams& params, double voxelMm)
{
    double best = std::numeric_limits<double>::infinity();
    auto score = [&](const Vec3d& e) { return params.rectumMm ? distance(e, *params.rectumMm) : e.z; };
    for (std::size_t i = 0; i < t.ends.size(); ++i)
        for (bool back : {false, true}) {
            const double sc = score(back ? t.ends[i].backMm : t.ends[i].frontMm);
            if (sc < best) {
                best = sc;
                t.first = static_cast<int>(i);
                t.firstReversed = back;
            }
        }
    // Re-trace the piece of `seed` from the end of the tube nearest to it, and start there.
    auto retraceFrom = [&](Slot seed) {
        const std::int32_t label = pieces.label[seed];
        for (std::size_t i = 0; i < t.paths.size(); ++i)
            if (t.paths[i].label == label) {
                t.set(i, tracer.trace(label, seed), voxelMm);
                t.first = static_cast<int>(i);
                t.firstReversed = false;
            }
        t.reseeded = true;
    };
    const Vec3d lowestMm = toVec(xf.indexToWorld(index.coord(seeds.lowestSlot)));
    const Vec3d start = t.firstReversed ? t.ends[t.first].backMm : t.ends[t.first].frontMm;
    if (params.rectumMm) {
        // The hint at an end: the lumen voxel nearest to it (on the cap wall for a hint outside
        // the lumen, such as the anus) within two depths of the end (the path stops where the
        // depth in the cap falls to 60% of the lumen radius, that far from the cap wall).
        const Vec3d seedMm = toVec(xf.indexToWorld(index.coord(seeds.rectumSeed)));
        const double reach = std::max(2.0 * std::max(0.0, depthAt(start)), 3.0 * voxelMm);
        if (distance(start, seedMm) > reach) retraceFrom(seeds.rectumSeed);
    } else if (start.z - lowestMm.z > LOWEST_END_SLACK_MM) {
        retraceFrom(seeds.lowestSlot);
    }
}

/// The far end's left-out branch: what the path leaves out there, kept for coverage.
struct FarEnd {
    std::optional<CenterlineFarBranch> branch;
    std::vector<Vec3d> leftOutMm;
};

/// Every 2 mm of `pts` from index `from` on, and its last point.
std::vector<Vec3d> axisFrom(const std::vector<Vec3d>& pts, std::size_t from)
{
    std::vector<Vec3d> axis;
    for (std::size_t i = from; i < pts.size(); ++i)
        if (axis.empty() || distance(axis.back(), pts[i]) >= 2.0) axis.push_back(pts[i]);
    if (!axis.empty() && axis.back() != pts.back()) axis.push_back(pts.back());
    return axis;
}

/// The chain's last piece: its index, whether it is travelled backwards, and its path in
/// travel order.
struct LastPiece {
    std::size_t index = 0;
    bool reversed = false;
    std::vector<Vec3d> pointsMm;
};

LastPiece lastPiece(const TracedPieces& t, const PieceChain& chain)
{
    LastPiece lp;
    const std::size_t lastPos = chain.order.size() - 1;
    lp.index = std::size_t(chain.order[lastPos]);
    lp.reversed = chain.reversed[lastPos];
    lp.pointsMm = t.paths[lp.index].pointsMm;
    if (lp.reversed) std::reverse(lp.pointsMm.begin(), lp.pointsMm.end());
    return lp;
}

/// Step 4b (centerline_far_end.h): when the last piece's path ends in a narrow tube off a wide
/// lumen (the terminal ileum off the cecum), the tube is plugged past its mouth and the farthest
/// voxel from the piece's near end is searched again. When that lies well beyond the mouth
/// (FAR_SAC_DEPTHS wide depths, in steps), the wide lumen has an end of its own that the path
/// skipped (the cecum below the valve): the piece is traced to it. Else (a narrow cecum, no wide
/// end beyond its mouth) the path stays.
FarEnd traceBelowIleum(TracedPieces& t, const PieceChain& chain, PieceTracer& tracer, const LumenIndex& index,
                       const Pieces& pieces, const SlotBits& holes, const openvdb::math::Transform& xf,
                       DepthProbe& depthAt, double voxelMm, double fineMm)
{
    FarEnd far;
    LastPiece lp = lastPiece(t, chain);
    const std::size_t last = lp.index;
    const bool reversed = lp.reversed;
    std::vector<Vec3d>& pts = lp.pointsMm;
    const auto narrow = narrowFarEnd(pts, [&](const Vec3d& p) { return depthAt(p); });
    if (!narrow) return far;
    const std::int32_t label = t.paths[last].label;
    const Vec3d mouth = pts[narrow->mouthIndex];
    Slot nearSlot = NO_SLOT, mouthSlot = NO_SLOT, farSlot = NO_SLOT;
    double nearMm = std::numeric_limits<double>::infinity(), mouthMm = nearMm, farMm = nearMm;
    SlotBits plugged = holes;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        if (pieces.label[s] != label) continue;
        const Vec3d w = toVec(xf.indexToWorld(index.coord(s)));
        const auto nearest = [&](const Vec3d& p, Slot& slot, double& best) {
            const double d = distance(w, p);
            if (d < best) {
                best = d;
                slot = s;
            }
        };
        nearest(pts.front(), nearSlot, nearMm);
        nearest(mouth, mouthSlot, mouthMm);
        nearest(pts.back(), farSlot, farMm);
        if (distance(w, narrow->plugMm) <= narrow->plugRadiusMm) plugged.set(s);
    }
    if (plugged.test(nearSlot) || plugged.test(mouthSlot)) return far;
    tracer.unreached(label);
    const Slot end = tracer.stepsFrom(plugged, nearSlot);
    const std::vector<std::int32_t>& steps = tracer.steps();
    const double beyondMm = double(steps[end] - steps[mouthSlot]) * voxelMm;
    if (steps[farSlot] >= 0 || beyondMm < FAR_SAC_DEPTHS * narrow->wideDepthMm) return far;
    PiecePath traced = tracer.trace(label, NO_SLOT, nearSlot, &plugged);
    // The tube's axis past the plug's centre.
    std::size_t plug = pts.size();
    for (std::size_t i = 0; i < pts.size() && plug == pts.size(); ++i)
        if (distance(pts[i], narrow->plugMm) < 0.5 * fineMm) plug = i;
    far.leftOutMm = axisFrom(pts, plug);
    CenterlineFarBranch info;
    info.mouthMm = mouth;
    info.endMm = pts.back();
    info.lengthMm = narrow->lengthMm;
    info.depthMm = narrow->narrowDepthMm;
    info.wideDepthMm = narrow->wideDepthMm;
    info.wideEndBeyondMouthMm = beyondMm;
    far.branch = info;
    if (reversed) std::reverse(traced.pointsMm.begin(), traced.pointsMm.end());
    t.set(last, std::move(traced), voxelMm);
    return far;
}

/// Step 4c: a thin tube at the far end with no wide end beyond: the appendix (or a thread of
/// ileum) off the cecum's end, at most APPENDIX_DEPTH_FRACTION as deep as the colon before it,
/// is no colon to fly: the path ends at its mouth, continued into the cecum's cap, and the
/// tube's axis is kept for coverage as the ileum's is.
FarEnd stopAtAppendix(TracedPieces& t, const PieceChain& chain, DepthProbe& depthAt, double voxelMm, double fineMm)
{
    FarEnd far;
    LastPiece lp = lastPiece(t, chain);
    const std::size_t last = lp.index;
    const bool reversed = lp.reversed;
    std::vector<Vec3d>& pts = lp.pointsMm;
    const auto mouth = thinFarEnd(pts, depthAt, fineMm);
    if (!mouth) return far;
    CenterlineFarBranch info;
    info.mouthMm = pts[mouth->index];
    info.endMm = pts.back();
    info.lengthMm = mouth->lengthMm;
    info.depthMm = mouth->thinDepthMm;
    info.wideDepthMm = mouth->wideDepthMm;
    far.branch = info;
    far.leftOutMm = axisFrom(pts, mouth->index);
    pts.resize(mouth->index + 1);
    extendEnd(pts, depthAt, fineMm);
    if (reversed) std::reverse(pts.begin(), pts.end());
    t.ends[last] = endsOf(pts, voxelMm);
    t.paths[last].pointsMm = std::move(pts);
    return far;
}

/// Step 5: one polyline, the pieces in chain order and bridges between them.
struct ChainedPath {
    struct Bridge {
        double startArc, endArc, startDepth, endDepth;
    };
    std::vector<Vec3d> pointsMm;
    std::vector<Bridge> bridges;
    std::vector<CenterlineBridgeInfo> info;
};

ChainedPath chainPieces(const TracedPieces& t, const PieceChain& chain, DepthProbe& depthAt, double fineMm)
{
    ChainedPath c;
    for (std::size_t k = 0; k < chain.order.size(); ++k) {
        std::vector<Vec3d> pts = t.paths[chain.order[k]].pointsMm;
        if (chain.reversed[k]) std::reverse(pts.begin(), pts.end());
        if (k > 0) {
            const Vec3d exit = c.pointsMm.back();
            const PieceEnds& from = t.ends[chain.order[k - 1]];
            const PieceEnds& to = t.ends[chain.order[k]];
            const Vec3d exitOut = chain.reversed[k - 1] ? from.frontOut : from.backOut;
            const Vec3d entryOut = chain.reversed[k] ? to.backOut : to.frontOut;
            const std::vector<Vec3d> curve = bridgeCurve(exit, exitOut, pts.front(), entryOut, fineMm);
            ChainedPath::Bridge b;
            b.startArc = arcLengths(c.pointsMm).back();
            b.startDepth = std::max(0.0, depthAt(exit));
            b.endDepth = std::max(0.0, depthAt(pts.front()));
            c.pointsMm.insert(c.pointsMm.end(), curve.begin() + 1, curve.end() - 1);
            const double bridgeLength = arcLengths(curve).back();
            b.endArc = b.startArc + bridgeLength;
            c.bridges.push_back(b);
            CenterlineBridgeInfo info;
            info.fromPiece = chain.order[k - 1];
            info.toPiece = chain.order[k];
            info.gapMm = distance(exit, pts.front());
            info.lengthMm = bridgeLength;
            c.info.push_back(info);
        }
        c.pointsMm.insert(c.pointsMm.end(), pts.begin(), pts.end());
    }
    return c;
}

/// Uniform arc-length resampling at stepMm from the rectum end; the remainder (< stepMm) at the
/// cecum end is dropped so that every step is exactly stepMm. Radii: D at the point; on a bridge
/// (no lumen to measure) linear in arc length between D at its two ends.
Centerline resampleChain(const ChainedPath& c, double stepMm, DepthProbe& depthAt)
{
    Centerline cl;
    cl.stepMm = stepMm;
    const std::vector<Vec3d>& pts = c.pointsMm;
    const std::vector<double> s = arcLengths(pts);
    if (pts.size() < 2 || !(s.back() > 0)) {
        CenterlinePoint p;
        p.positionMm = pts.front();
        p.radiusMm = std::max(0.0, depthAt(p.positionMm));
        cl.points.push_back(p);
    } else {
        const std::size_t count = static_cast<std::size_t>(std::floor(s.back() / stepMm + 1e-9)) + 1;
        cl.points.resize(count);
        std::size_t hint = 0, bridge = 0;
        for (std::size_t i = 0; i < count; ++i) {
            const double arc = double(i) * stepMm;
            CenterlinePoint& p = cl.points[i];
            p.positionMm = pointAt(pts, s, arc, hint);
            while (bridge < c.bridges.size() && c.bridges[bridge].endArc <= arc) ++bridge;
            if (bridge < c.bridges.size() && c.bridges[bridge].startArc < arc) {
                const ChainedPath::Bridge& b = c.bridges[bridge];
                const double t = (arc - b.startArc) / std::max(b.endArc - b.startArc, 1e-9);
                p.bridged = true;
                p.radiusMm = b.startDepth + (b.endDepth - b.startDepth) * t;
            } else {
                p.radiusMm = std::max(0.0, depthAt(p.positionMm));
            }
        }
    }
    computeTangentsAndNormals(cl);
    return cl;
}

/// Every piece (by size, as UsedPieces::bySize) with what the path made of it; bridges name
/// pieces by that order.
void reportPieces(const TracedPieces& t, const PieceChain& chain, const Pieces& pieces,
                  const std::vector<std::int32_t>& bySize, double voxelMl, CenterlineReport& report)
{
    std::vector<int> infoOf(pieces.size.size(), -1);
    for (std::size_t r = 0; r < bySize.size(); ++r) {
        CenterlinePieceInfo info;
        info.volumeMl = double(pieces.size[bySize[r]]) * voxelMl;
        infoOf[bySize[r]] = static_cast<int>(r);
        report.pieces.push_back(info);
    }
    for (std::size_t k = 0; k < chain.order.size(); ++k) {
        const PiecePath& path = t.paths[chain.order[k]];
        CenterlinePieceInfo& info = report.pieces[infoOf[path.label]];
        info.used = true;
        info.chainIndex = static_cast<int>(k);
        info.pathLengthMm = arcLengths(path.pointsMm).back();
        info.routeSearchedOn = path.searchedOn;
        info.entryMm = chain.reversed[k] ? path.pointsMm.back() : path.pointsMm.front();
        info.exitMm = chain.reversed[k] ? path.pointsMm.front() : path.pointsMm.back();
    }
    for (CenterlineBridgeInfo& b : report.bridges) {
        b.fromPiece = infoOf[t.paths[b.fromPiece].label];
        b.toPiece = infoOf[t.paths[b.toPiece].label];
    }
}

} // namespace

Centerline extractCenterline(const openvdb::FloatGrid& sdfGrid, const CenterlineParams& params,
                             Progress* progress, CenterlineReport* report)
{
    validate(sdfGrid, params);
    const openvdb::math::Transform& xf = sdfGrid.transform();
    const double voxelMm = xf.voxelSize()[0];
    const double voxelMl = voxelMm * voxelMm * voxelMm / 1000.0;
    reportProgress(progress, 0.0, "index lumen voxels");

    // A level set has no active tiles; voxelise a copy if a caller hands one in anyway.
    openvdb::FloatGrid::ConstPtr grid = sdfGrid.copy();
    if (sdfGrid.tree().hasActiveTiles()) {
        openvdb::FloatGrid::Ptr dense = sdfGrid.deepCopy();
        dense->tree().voxelizeActiveTiles();
        grid = dense;
    }

    // 1. Lumen voxels (sdf < 0) and their depth D = -sdf (mm).
    const LumenIndex index = buildIndex(grid->tree());
    if (index.slotCount() == 0)
        throw InputError("extractCenterline: the lumen is empty (no active sdf voxel below 0)");
    reportProgress(progress, 0.1, "lumen pieces");

    // 2. Pieces, and those the path takes.
    const SlotBits holes = holeBits(index);
    const Pieces pieces = labelPieces(index, holes, progress);
    const UsedPieces use = usedPieces(pieces, voxelMl, params);
    const RectumSeeds seeds = rectumSeeds(index, xf, pieces, use.used, params);

    // 3. Per piece, the minimal path and its refinement. Sampling of the paths before the final
    // resampling: a quarter voxel, at most 0.5 mm, and independent of stepMm: the refinement
    // (trimming, sections, smoothing) works on these samples, and on a coarse grid (3 mm voxels)
    // a spacing that followed the output step moved the path by up to 15 mm between --step-mm 1
    // and 2. Linear interpolation between samples this close is exact to well under a
    // micrometre on colon bends.
    const double fineMm = std::min(0.25 * voxelMm, 0.5);
    PieceTracer tracer(index, holes, pieces, *grid, params, fineMm, progress);
    TracedPieces traced;
    for (std::size_t u = 0; u < use.used.size(); ++u) {
        reportProgress(progress, 0.2 + 0.6 * double(u) / double(use.used.size()), "minimal path");
        traced.paths.push_back(tracer.trace(use.used[u], NO_SLOT));
    }
    reportProgress(progress, 0.8, "order and bridge pieces");

    // 4. The rectum end and the order of the pieces; the far end's ileum and appendix.
    DepthProbe depthAt(*grid);
    traced.ends.resize(traced.paths.size());
    for (std::size_t i = 0; i < traced.paths.size(); ++i) traced.ends[i] = endsOf(traced.paths[i].pointsMm, voxelMm);
    chooseRectumEnd(traced, tracer, index, pieces, xf, seeds, depthAt, params, voxelMm);
    const PieceChain chain = orderPieces(traced.ends, traced.first, traced.firstReversed, params.bridgeTurnMmPerRad);
    FarEnd far = traceBelowIleum(traced, chain, tracer, index, pieces, holes, xf, depthAt, voxelMm, fineMm);
    if (!far.branch) far = stopAtAppendix(traced, chain, depthAt, voxelMm, fineMm);

    // 5. One polyline, resampled every stepMm with radii and frames.
    const ChainedPath chained = chainPieces(traced, chain, depthAt, fineMm);
    Centerline cl = resampleChain(chained, params.stepMm, depthAt);
    if (far.branch) {
        cl.leftOutBranchMm = far.leftOutMm;
        cl.leftOutBranchRadiusMm = far.branch->depthMm;
    }

    if (report) {
        report->pieces.clear();
        report->bridges = chained.info;
        report->rectumRule = params.rectumMm ? (traced.reseeded ? "end of the tube nearest to rectum_mm"
                                                                : "piece end nearest to rectum_mm")
                             : traced.reseeded ? "end nearest to the lowest lumen voxel"
                                               : "lowest end";
        report->lowestLumenMm = toVec(xf.indexToWorld(index.coord(seeds.lowestSlot)));
        report->nearWall = nearWallStretches(cl, params);
        report->farBranchLeftOut = far.branch;
        report->leftOut = leftOutLumen(index, xf, cl, LEFT_OUT_MIN_ML);
        reportTurns(cl, *report);
        reportPieces(traced, chain, pieces, use.bySize, voxelMl, *report);
    }
    reportProgress(progress, 1.0, "centerline done");
    return cl;
}

namespace detail {

std::vector<Vec3d> removePathKinks(const std::vector<Vec3d>& fine, const openvdb::FloatGrid& sdf, double fineMm)
{
    return removeKinks(resampleEven(fine, fineMm), sdf, fineMm);
}

} // namespace detail

} // namespace flyover
