/// @file route_search.h
/// @brief Minimal-cost routes over the lumen index (lumen_index.h): the searches of the
///        centerline's minimal path (centerline.cpp), deterministic.
///
/// - dijkstra(): one source, stops once the target is settled; leaves dist and prev.
/// - shortestRoute(): the same minimal cost, searched from both ends at once (by default),
///   each end's search on its own thread. On a 2.4 m real colon whose core is split, the whole
///   piece (10.5 M voxels) is searched; the search from one end took ~3 s on one core.
///
/// Both use a ring of buckets of width just below the smallest edge cost (Dial's algorithm
/// generalised to real weights): a relaxation from bucket k always lands in a later bucket, and
/// every slot of bucket k is final when the bucket is reached, so processing bucket by bucket
/// is exact while each push and pop is O(1). Where the weight range is too wide for a ring of
/// reasonable size (a steep wallPenalty), a binary heap takes over (one end only).
///
/// Determinism: each end's search is serial and breaks ties by insertion order. The two ends
/// advance in rounds of whole buckets, each round of a fixed number of settled slots per end,
/// and meet only at the barrier between rounds; so the route does not depend on the thread
/// count or on timing. Where several routes have exactly the same cost, the two searches may
/// return different ones of them.
///
/// allowed[s] must be 0 at the index's holes (slots of no lumen voxel): the searches read
/// `allowed` alone, not the index's depths as well (one memory read less per neighbour).
/// edgeCost(from, to, stepIndex) must lie in [minEdge, maxEdge], minEdge > 0, or be +infinity
/// (no edge); for shortestRoute it must also be symmetric (the cost of a step back equals the
/// cost of the step), as the centerline's costs are.
#pragma once

#include "colon/lumen_index.h"
#include "volume/threads.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <queue>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

namespace flyover::route_search {

using lumen_index::checkCancelled;
using lumen_index::LumenIndex;
using lumen_index::NO_SLOT;
using lumen_index::Slot;

/// An allocator whose resize() leaves new elements uninitialised: a search's per-slot arrays
/// are written only where it reaches (a bit per slot says where), so the pages of the slots it
/// never reaches are never touched and take no memory.
template<typename T>
struct DefaultInit : std::allocator<T> {
    template<typename U>
    struct rebind {
        using other = DefaultInit<U>;
    };
    DefaultInit() = default;
    template<typename U>
    DefaultInit(const DefaultInit<U>&) noexcept {}
    template<typename U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>)
    {
        ::new (static_cast<void*>(p)) U;
    }
    template<typename U, typename... Args>
    void construct(U* p, Args&&... args)
    {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

/// A per-slot array of a search: valid only at the slots the search reached.
template<typename T>
using SlotArray = std::vector<T, DefaultInit<T>>;

/// Largest ring of buckets before the binary heap takes over.
constexpr double MAX_RING = double(1 << 20);

/// The bucket width for edge costs of at least minEdge, or 0 when the weight range needs the
/// binary heap.
inline double ringWidth(double minEdge, double maxEdge)
{
    const double width = 0.999 * minEdge;
    return width > 0 && maxEdge / width < MAX_RING ? width : 0.0;
}

/// One end of a search by buckets: dist, prev and the ring, advanced a batch of whole buckets
/// at a time.
template<int STRIDE, typename EdgeCost>
class BucketFront {
public:
    BucketFront(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, EdgeCost& edgeCost,
                double minEdge, double maxEdge, Slot source, SlotArray<double>& dist, SlotArray<Slot>& prev,
                bool recordTouched)
        : mIndex(index), mAllowed(allowed), mEdgeCost(edgeCost), mWidth(ringWidth(minEdge, maxEdge)),
          mRecordTouched(recordTouched), mReached(index.blockOrigin.size()),
          // Stride 1 walks the closed bits (forEachClearNeighbour), so they hold the slots not
          // allowed too; stride 2 tests `allowed` itself. A settled neighbour is never improved
          // (it lies in an earlier bucket, or in the same one less than a bucket width lower,
          // and every edge is longer), so skipping it by its bit is exact.
          mClosed(STRIDE == 1 ? lumen_index::bitsWhere(index, [&](Slot s) { return !allowed[s]; })
                              : lumen_index::SlotBits(index.blockOrigin.size())),
          mBuckets(static_cast<std::size_t>(std::ceil(maxEdge / mWidth)) + 2), dist(dist), prev(prev)
    {
        dist.resize(index.slotCount());  // uninitialised: read only where mReached is set
        prev.resize(index.slotCount());
        mReached.set(source);
        prev[source] = NO_SLOT;
        dist[source] = 0.0;
        mBuckets[0].push_back(source);
        mPending = 1;
        if (mRecordTouched) touched.push_back(source);
    }

    /// Processes whole buckets in order until at least `quota` slots were settled by this call,
    /// `stopAt` is settled (the search is then finished: returns true), or nothing is left.
    /// With recordTouched, appends each slot whose distance dropped to `touched`.
    bool advance(std::size_t quota, Slot stopAt, Progress* progress)
    {
        const std::size_t ring = mBuckets.size();
        std::size_t settledNow = 0;
        while (mPending > 0 && settledNow < quota) {
            std::vector<Slot>& bucket = mBuckets[mCurrent % ring];
            for (std::size_t i = 0; i < bucket.size(); ++i) {  // by index: see below
                const Slot u = bucket[i];
                --mPending;
                if (mClosed.testAndSet(u)) continue;  // stale entry from before an improvement
                if (u == stopAt) return true;
                ++settledNow;
                if ((++mSettled & 0xfffff) == 0) checkCancelled(progress);
                const double d = dist[u];
                auto relax = [&](Slot v, int k) {
                    const double nd = d + mEdgeCost(u, v, k);  // +infinity: no edge
                    if (nd < distance(v)) {
                        mReached.set(v);
                        dist[v] = nd;
                        prev[v] = u;
                        if (mRecordTouched) touched.push_back(v);
                        // Lands in a later bucket; should rounding ever put it in the current
                        // one, the index loop above still visits it.
                        const std::uint64_t b =
                            std::max<std::uint64_t>(mCurrent, static_cast<std::uint64_t>(nd / mWidth));
                        mBuckets[b % ring].push_back(v);
                        ++mPending;
                    }
                };
                if constexpr (STRIDE == 1) {
                    lumen_index::forEachClearNeighbour(mIndex, mClosed, u, relax);
                } else {
                    mIndex.template forEachNeighbourSlot<STRIDE>(u, [&](Slot v, int k) {
                        if (mAllowed[v]) relax(v, k);
                    });
                }
            }
            bucket.clear();
            ++mCurrent;
        }
        return false;
    }

    bool exhausted() const { return mPending == 0; }
    /// The distance found so far from the source; +infinity where the search has not reached.
    double distance(Slot s) const { return mReached.test(s) ? dist[s] : std::numeric_limits<double>::infinity(); }
    /// Every slot not yet settled is at least this far from the source (up to rounding).
    double radius() const { return double(mCurrent) * mWidth; }
    double width() const { return mWidth; }

private:
    const LumenIndex& mIndex;
    const std::vector<std::uint8_t>& mAllowed;
    EdgeCost& mEdgeCost;
    double mWidth;
    bool mRecordTouched;
    lumen_index::SlotBits mReached;      ///< where dist and prev are valid
    lumen_index::SlotBits mClosed;       ///< settled (stride 1: or not allowed)
    std::vector<std::vector<Slot>> mBuckets;
    std::uint64_t mCurrent = 0;
    std::size_t mPending = 0;
    std::size_t mSettled = 0;

public:
    SlotArray<double>& dist;  ///< valid where reached (distance())
    SlotArray<Slot>& prev;    ///< valid where reached; NO_SLOT at the source
    std::vector<Slot> touched;  ///< slots whose distance dropped since the caller last cleared it
};

/// Single-source search over the 26-connected lumen slots with allowed[s] != 0 (with STRIDE 2
/// the steps join voxels two apart, see LumenIndex::forEachNeighbour). Stops once `target` is
/// settled; returns whether it was reached. dist[target] is then its distance, and `prev` leads
/// back from it (dist and prev are valid only at the slots the search reached).
template<int STRIDE, typename EdgeCost>
bool dijkstra(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, Slot source, Slot target,
              EdgeCost&& edgeCost, double minEdge, double maxEdge, SlotArray<double>& dist,
              SlotArray<Slot>& prev, Progress* progress)
{
    if (ringWidth(minEdge, maxEdge) > 0) {
        BucketFront<STRIDE, std::remove_reference_t<EdgeCost>> front(index, allowed, edgeCost, minEdge, maxEdge,
                                                                     source, dist, prev, false);
        return front.advance(std::numeric_limits<std::size_t>::max(), target, progress);
    }
    dist.assign(index.slotCount(), std::numeric_limits<double>::infinity());
    prev.assign(index.slotCount(), NO_SLOT);
    dist[source] = 0.0;
    std::size_t settled = 0;
    using Entry = std::pair<double, Slot>;
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> heap;
    heap.push({0.0, source});
    while (!heap.empty()) {
        const auto [d, u] = heap.top();
        heap.pop();
        if (d > dist[u]) continue;  // stale entry
        if (u == target) return true;
        if ((++settled & 0xfffff) == 0) checkCancelled(progress);
        index.forEachNeighbourSlot<STRIDE>(u, [&](Slot v, int k) {
            if (!allowed[v]) return;
            const double nd = d + edgeCost(u, v, k);
            if (nd < dist[v]) {
                dist[v] = nd;
                prev[v] = u;
                heap.push({nd, v});
            }
        });
    }
    return false;
}

/// Runs two jobs side by side: the first on the caller's thread, the second on a helper
/// thread kept for the whole search; or one after the other when only one thread may run
/// (threadsThatMayRun()). Not TBB tasks: the centerline runs on a thread of its own beside
/// other stages, and a task left for TBB's workers could wait for one that another stage holds
/// (measured: the second end then ran after the first, on one core).
class SideBySide {
public:
    SideBySide() : mTwo(threadsThatMayRun() > 1)
    {
        if (mTwo) mHelper = std::thread([this] { serve(); });
    }
    SideBySide(const SideBySide&) = delete;
    SideBySide& operator=(const SideBySide&) = delete;
    ~SideBySide()
    {
        if (!mTwo) return;
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mQuit = true;
        }
        mWake.notify_all();
        mHelper.join();
    }

    /// Returns when both have returned; rethrows what either threw (the first job's first).
    void run(const std::function<void()>& here, const std::function<void()>& there)
    {
        if (mTwo) {
            std::lock_guard<std::mutex> lock(mMutex);
            mJob = &there;
        }
        mWake.notify_all();
        std::exception_ptr hereError;
        try {
            here();
        } catch (...) {
            hereError = std::current_exception();
        }
        if (mTwo) {
            std::unique_lock<std::mutex> lock(mMutex);
            mWake.wait(lock, [this] { return mJob == nullptr; });
        } else {
            runJob(there);
        }
        if (hereError) std::rethrow_exception(hereError);
        if (mThereError) std::rethrow_exception(mThereError);
    }

private:
    void serve()
    {
        std::unique_lock<std::mutex> lock(mMutex);
        for (;;) {
            mWake.wait(lock, [this] { return mQuit || mJob != nullptr; });
            if (mJob == nullptr) return;  // quit
            const std::function<void()>& job = *mJob;
            lock.unlock();
            runJob(job);
            lock.lock();
            mJob = nullptr;
            mWake.notify_all();
        }
    }

    /// Runs the second job; what it throws is kept for run() (its thread alone writes it).
    void runJob(const std::function<void()>& job)
    {
        mThereError = nullptr;
        try {
            job();
        } catch (...) {
            mThereError = std::current_exception();
        }
    }

    bool mTwo;
    std::mutex mMutex;
    std::condition_variable mWake;
    const std::function<void()>* mJob = nullptr;
    std::exception_ptr mThereError;
    bool mQuit = false;
    std::thread mHelper;  ///< last: started once the members it uses exist
};

/// Reusable memory of shortestRoute (two ends' distances and predecessors).
struct RouteWorkspace {
    SlotArray<double> dist[2];
    SlotArray<Slot> prev[2];
};

/// Slots settled per end and round of shortestRoute: a few milliseconds of work, so that the
/// barriers cost little and the two ends stay in step.
constexpr std::size_t ROUND_SLOTS = 1 << 15;

/// How shortestRoute searches.
struct RouteOptions {
    /// From both ends at once (each on its own thread when two may run), or from the source
    /// alone: the second end costs a second set of per-slot arrays (12 bytes per slot of the
    /// whole index, ~100 MB on the full phantom), which a small search does not repay.
    bool bothEnds = true;
    /// Slots each end settles per round (tests use small rounds to make the ends meet
    /// mid-round).
    std::size_t roundSlots = ROUND_SLOTS;
};

/// A minimal-cost route from `source` to `target` (both included, in that order) over the
/// slots with allowed[s] != 0; false when none exists. Same cost as dijkstra()'s route (see
/// the file comment for ties).
template<int STRIDE, typename EdgeCost>
bool shortestRoute(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, Slot source, Slot target,
                   EdgeCost&& edgeCost, double minEdge, double maxEdge, RouteWorkspace& work,
                   std::vector<Slot>& route, Progress* progress, const RouteOptions& options = {})
{
    route.clear();
    if (source == target) {
        route.push_back(source);
        return true;
    }
    if (!options.bothEnds || ringWidth(minEdge, maxEdge) == 0) {  // one end (the heap: always)
        if (!dijkstra<STRIDE>(index, allowed, source, target, edgeCost, minEdge, maxEdge, work.dist[0],
                              work.prev[0], progress))
            return false;
        for (Slot s = target; s != NO_SLOT; s = work.prev[0][s]) route.push_back(s);
        std::reverse(route.begin(), route.end());
        return true;
    }
    using Front = BucketFront<STRIDE, std::remove_reference_t<EdgeCost>>;
    Front from(index, allowed, edgeCost, minEdge, maxEdge, source, work.dist[0], work.prev[0], true);
    Front to(index, allowed, edgeCost, minEdge, maxEdge, target, work.dist[1], work.prev[1], true);
    // Which blocks of 512 slots each end has touched: a slot is looked up in the other end's
    // distances only where that end has been, which spares a cache miss per slot until the
    // ends meet. Each end writes its own flags during a round and reads the other's only
    // between rounds.
    const std::size_t blocks = (index.slotCount() + lumen_index::LEAF_VOXELS - 1) / lumen_index::LEAF_VOXELS;
    std::vector<std::uint8_t> seen[2] = {std::vector<std::uint8_t>(blocks, 0), std::vector<std::uint8_t>(blocks, 0)};
    struct Meeting {
        double cost = std::numeric_limits<double>::infinity();
        Slot slot = NO_SLOT;
        bool operator<(const Meeting& o) const { return cost < o.cost || (cost == o.cost && slot < o.slot); }
    };
    Meeting best;
    Front* fronts[2] = {&from, &to};
    SideBySide sides;
    bool finished[2] = {false, false};
    for (;;) {
        checkCancelled(progress);
        // A round: each end settles its quota of slots, or settles the other's source (then its
        // own distances alone hold a minimal route).
        sides.run([&] { finished[0] = from.advance(options.roundSlots, target, progress); },
                  [&] { finished[1] = to.advance(options.roundSlots, source, progress); });
        if (finished[0] || finished[1]) {
            const int e = finished[0] ? 0 : 1;
            const SlotArray<Slot>& prev = fronts[e]->prev;
            for (Slot s = e == 0 ? target : source; s != NO_SLOT; s = prev[s]) route.push_back(s);
            if (e == 0) std::reverse(route.begin(), route.end());
            return true;
        }
        // Where the ends meet: a slot reached from both, least total cost first.
        Meeting found[2];
        auto meet = [&](int e) {
            Front& self = *fronts[e];
            const Front& other = *fronts[1 - e];
            for (Slot s : self.touched) {
                if (!seen[1 - e][s / lumen_index::LEAF_VOXELS]) continue;
                const double d = other.distance(s);
                if (d == std::numeric_limits<double>::infinity()) continue;
                const Meeting m{self.dist[s] + d, s};
                if (m < found[e]) found[e] = m;
            }
        };
        // The flags first (each end its own), then the lookups (each end reads the other's).
        sides.run([&] { for (Slot s : from.touched) seen[0][s / lumen_index::LEAF_VOXELS] = 1; },
                  [&] { for (Slot s : to.touched) seen[1][s / lumen_index::LEAF_VOXELS] = 1; });
        sides.run([&] { meet(0); }, [&] { meet(1); });
        from.touched.clear();
        to.touched.clear();
        best = std::min({best, found[0], found[1]});
        // A route cheaper than the best meeting steps somewhere from a slot the source's end
        // has settled to one it has not; that one lies at least the source's radius from the
        // source, so at most (cost - that radius) from the target: within the target's radius
        // once the radii add up to the cost, hence settled there too, a meeting already seen.
        // So once they add up to the best meeting's cost (one bucket of slack for rounding),
        // it is minimal.
        if (best.slot != NO_SLOT && from.radius() + to.radius() >= best.cost + from.width()) break;
        // An end that has settled all it can reach without the other's source: no route.
        if (from.exhausted() || to.exhausted()) return false;
    }
    for (Slot s = best.slot; s != NO_SLOT; s = from.prev[s]) route.push_back(s);
    std::reverse(route.begin(), route.end());
    for (Slot s = to.prev[best.slot]; s != NO_SLOT; s = to.prev[s]) route.push_back(s);
    return true;
}

} // namespace flyover::route_search
