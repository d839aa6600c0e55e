// Steps 1-3 of the contact search (contact_regions.h). Per-slot flags are bits, a block's 512
// in one cache line (SlotBits), so that testing a voxel's 26 neighbours reads a few lines
// instead of 26 scattered bytes or words; the searches are deterministic: the same regions on
// any number of threads.
#include "colon/contact_regions.h"
#include "volume/threads.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

namespace flyover::contact_regions {

using namespace lumen_index;

namespace {

/// Step 1: the cores, as the bit of every slot that is not a core voxel.
SlotBits notCoreBits(const LumenIndex& index, double voxelMm)
{
    const std::size_t blocks = index.blockOrigin.size();
    SlotBits notCore(blocks);
    const std::vector<float> nearby = nearbyMaxDepth(index);
    const float minCore = static_cast<float>(voxelMm);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t blk = r.begin(); blk != r.end(); ++blk) {
            const float half = 0.5f * nearby[blk];
            for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s) {
                const float d = index.depthMm[s];
                if (!(d >= minCore && d >= half)) notCore.set(s);
            }
        }
    });
    return notCore;
}

/// Step 2's shells: per core voxel, the shell of its breadth-first steps from the first voxel
/// (in slot order) of its core piece; -1 elsewhere.
std::vector<std::int32_t> coreShells(const LumenIndex& index, const SlotBits& notCore, double voxelMm, double chunkMm,
                                     Progress* progress)
{
    const std::size_t n = index.slotCount();
    std::vector<std::int32_t> shell(n, -1);
    const double shellSteps = std::max(1.0, chunkMm / (1.2 * voxelMm));
    auto shellOf = [&](std::int32_t steps) { return static_cast<std::int32_t>(double(steps) / shellSteps); };
    std::vector<std::pair<Slot, std::int32_t>> stepQueue;
    SlotBits seen = notCore;  // and the core voxels reached
    for (Slot s = 0; s < n; ++s) {
        if (seen.test(s)) continue;
        stepQueue.assign(1, {s, 0});
        seen.set(s);
        shell[s] = shellOf(0);
        for (std::size_t head = 0; head < stepQueue.size(); ++head) {
            if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
            const auto [u, steps] = stepQueue[head];
            forEachClearNeighbour(index, seen, u, [&](Slot t) {
                seen.set(t);
                shell[t] = shellOf(steps + 1);
                stepQueue.push_back({t, steps + 1});
            });
        }
    }
    return shell;
}

/// Step 2's parts: each connected part of a shell within the cores becomes a region (ids from
/// 0, in slot order of its first voxel) in `region`; returns their count. `labelled` holds the
/// not-core bits (step 1) and is used up.
std::int32_t labelShellParts(const LumenIndex& index, const std::vector<std::int32_t>& shell, SlotBits labelled,
                             std::vector<std::int32_t>& region, Progress* progress)
{
    const std::size_t n = index.slotCount();
    std::int32_t regionCount = 0;
    std::vector<Slot> queue;
    for (Slot s = 0; s < n; ++s) {
        if (labelled.test(s)) continue;
        const std::int32_t id = regionCount++;
        const std::int32_t part = shell[s];  // every voxel of the part is in this shell
        queue.assign(1, s);
        labelled.set(s);
        region[s] = id;
        for (std::size_t head = 0; head < queue.size(); ++head) {
            if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
            forEachClearNeighbour(index, labelled, queue[head], [&](Slot t) {
                if (shell[t] != part) return;
                labelled.set(t);
                region[t] = id;
                queue.push_back(t);
            });
        }
    }
    return regionCount;
}

/// The largest depth D of the lumen's slots (0 when none is positive).
float maxDepthMm(const LumenIndex& index)
{
    float maxDepth = 0.0f;
    for (std::size_t s = 0; s < index.slotCount(); ++s) maxDepth = std::max(maxDepth, index.depthMm[s]);
    return maxDepth;
}

/// A bucket entry carries the region it floods, so that a voxel's own region is not
/// read back from `region` (a scattered read) when it is taken.
struct Entry {
    Slot s;
    std::int32_t r;
};

/// A neighbour listed in the first pass of a large batch.
struct Listed {
    Slot t;
    std::int32_t r;
    std::int32_t code;  ///< region[t] when listed: UNREACHED - its bin
};

/// What `region` holds for a lumen voxel not yet in a region, less its bin.
constexpr std::int32_t UNREACHED = -3;

/// Step 3: the priority flood by decreasing D from the regions of step 2 (lumenRegions).
class RegionFlood {
public:
    RegionFlood(const LumenIndex& index, double voxelMm, std::vector<std::int32_t>& region, Progress* progress,
                const FloodOptions& flood);
    /// Takes the buckets from the deepest down; lumen voxels left unreached keep their bin.
    void run();

private:
    int binOf(Slot s) const { return std::min(bins_ - 1, static_cast<int>(double(index_.depthMm[s]) / binMm_)); }
    /// Takes the entries i to end of bucket b one at a time.
    void takeOneByOne(int b, std::size_t i, std::size_t end);
    /// Takes the entries i to end of bucket b in two passes (contact_regions.h): the first
    /// lists, per task of consecutive entries, the neighbours not taken when the batch began,
    /// each with the region of the first of the task's entries to reach it and its bin (read
    /// from `region` there, in parallel); the second takes them in the queue's order.
    void takeInTwoPasses(int b, std::size_t i, std::size_t end);

    const LumenIndex& index_;
    std::vector<std::int32_t>& region_;
    Progress* progress_;
    const FloodOptions& flood_;
    const double binMm_;
    const int bins_;
    std::vector<std::vector<Entry>> buckets_;
    SlotBits taken_;
    const int threads_;
    const std::size_t chunkEntries_;
    tbb::enumerable_thread_specific<SlotBits> listedBits_;
    std::vector<std::vector<Listed>> lists_;
    tbb::enumerable_thread_specific<std::vector<Listed>> scratch_;
    std::size_t done_ = 0;
};

RegionFlood::RegionFlood(const LumenIndex& index, double voxelMm, std::vector<std::int32_t>& region,
                         Progress* progress, const FloodOptions& flood)
    : index_(index), region_(region), progress_(progress), flood_(flood), binMm_(0.25 * voxelMm),
      bins_(static_cast<int>(maxDepthMm(index) / binMm_) + 1), buckets_(static_cast<std::size_t>(bins_)),
      taken_(index.blockOrigin.size()), threads_(threadsThatMayRun()),
      chunkEntries_(std::max<std::size_t>(1, flood.chunkEntries)),
      listedBits_([blocks = index.blockOrigin.size()] { return SlotBits(blocks); })
{
    for (Slot s = 0; s < index_.slotCount(); ++s)
        if (region_[s] >= 0) buckets_[binOf(s)].push_back({s, region_[s]});
    // Whether a slot is taken (a hole or already in a region): one bit per slot, a block's
    // 512 bits in one cache line, so that testing the 26 neighbours of a voxel reads at
    // most 8 lines (its block's and its neighbour blocks') instead of 26 scattered reads.
    // A lumen voxel not yet in a region holds its bin in `region` (UNREACHED - bin < 0), so
    // that taking it reads and writes one scattered value instead of its depth and its
    // region. The same flood, the same regions.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, index_.blockOrigin.size(), 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t blk = r.begin(); blk != r.end(); ++blk)
            for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s) {
                if (region_[s] >= 0 || !index_.isLumen(s)) taken_.set(s);
                else region_[s] = UNREACHED - binOf(s);
            }
    });
}

void RegionFlood::run()
{
    for (int b = bins_ - 1; b >= 0; --b) {
        std::vector<Entry>& bucket = buckets_[b];
        std::size_t i = 0;
        while (i < bucket.size()) {  // grows while visited
            const std::size_t end = bucket.size();
            if (threads_ < 2 || end - i < std::max<std::size_t>(1, flood_.minParallelBatch))
                takeOneByOne(b, i, end);
            else
                takeInTwoPasses(b, i, end);
            i = end;
        }
        std::vector<Entry>().swap(bucket);
    }
}

void RegionFlood::takeOneByOne(int b, std::size_t i, std::size_t end)
{
    std::vector<Entry>& bucket = buckets_[b];
    for (; i < end; ++i) {
        if ((++done_ & 0xfffff) == 0) checkCancelled(progress_);
        const Entry e = bucket[i];
        forEachClearNeighbour(index_, taken_, e.s, [&](Slot t) {
            taken_.set(t);
            const int bin = UNREACHED - region_[t];
            region_[t] = e.r;
            buckets_[std::min(b, bin)].push_back({t, e.r});
        });
    }
}

void RegionFlood::takeInTwoPasses(int b, std::size_t i, std::size_t end)
{
    const std::vector<Entry>& bucket = buckets_[b];
    checkCancelled(progress_);
    const std::size_t tasks = (end - i + chunkEntries_ - 1) / chunkEntries_;
    if (lists_.size() < tasks) lists_.resize(tasks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tasks, 1),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        SlotBits& mine = listedBits_.local();
        std::vector<Listed>& out = scratch_.local();  // not lists[task]: no false sharing
        for (std::size_t task = r.begin(); task != r.end(); ++task) {
            out.clear();
            const std::size_t from = i + task * chunkEntries_, to = std::min(end, from + chunkEntries_);
            for (std::size_t j = from; j < to; ++j) {
                const Entry e = bucket[j];
                forEachClearNeighbour(index_, taken_, e.s, [&](Slot t) {
                    if (mine.testAndSet(t)) return;
                    out.push_back({t, e.r, region_[t]});
                });
            }
            for (const Listed& l : out) mine.reset(l.t);
            lists_[task].swap(out);
        }
    });
    for (std::size_t task = 0; task < tasks; ++task)
        for (const Listed& l : lists_[task]) {
            if (taken_.testAndSet(l.t)) continue;
            region_[l.t] = l.r;
            buckets_[std::min(b, UNREACHED - l.code)].push_back({l.t, l.r});
        }
    done_ += end - i;
}

} // namespace

Regions lumenRegions(const LumenIndex& index, double voxelMm, double chunkMm, Progress* progress,
                     const FloodOptions& flood)
{
    const std::size_t n = index.slotCount();
    // 1. Cores: the bit of every slot that is not a core voxel is set (SlotBits: a block's bits
    // in one cache line), so that the searches below find the core voxels not yet reached as
    // clear bits (forEachClearNeighbour).
    SlotBits notCore = notCoreBits(index, voxelMm);
    reportProgress(progress, 0.15, "contacts: core chunks");

    // 2. Chunks: shells of breadth-first steps within each core piece, then connected parts of
    // each shell. A 26-step is up to sqrt(3) voxels long: shells count steps of ~1.2 voxels.
    // The queues carry the steps, the bits say what was reached: `shell` is the only per-slot
    // array read, once per core neighbour of a voxel of the same part.
    std::vector<std::int32_t> region(n, -1);
    std::int32_t regionCount = 0;
    {
        const std::vector<std::int32_t> shell = coreShells(index, notCore, voxelMm, chunkMm, progress);
        regionCount = labelShellParts(index, shell, std::move(notCore), region, progress);
    }
    reportProgress(progress, 0.3, "contacts: regions");

    // 3. Regions: priority flood by decreasing D. A voxel takes the region of the voxel that
    // reaches it first; buckets a quarter voxel wide; a voxel deeper than the current level
    // (rare: a non-core voxel behind a saddle) is processed at the current level.
    RegionFlood(index, voxelMm, region, progress, flood).run();
    // Lumen voxels left unreached (in pieces without core voxels) still hold their bin (< 0).
    // Pieces without any core voxel (too thin everywhere): one region each.
    labelUnreachedPieces(index, region, regionCount);
    return {std::move(region), regionCount};
}

void labelUnreachedPieces(const LumenIndex& index, std::vector<std::int32_t>& region, std::int32_t& count)
{
    std::vector<Slot> queue;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        if (!index.isLumen(s) || region[s] >= 0) continue;
        const std::int32_t id = count++;
        queue.assign(1, s);
        region[s] = id;
        for (std::size_t head = 0; head < queue.size(); ++head)
            index.forEachNeighbour(queue[head], [&](Slot t, int) {
                if (region[t] < 0) {
                    region[t] = id;
                    queue.push_back(t);
                }
            });
    }
}

std::size_t piecesWithout(const LumenIndex& index, const Regions& regions,
                          const std::vector<std::pair<std::int32_t, std::int32_t>>& touching,
                          const std::vector<std::uint8_t>& removed, const std::vector<Slot>& removedSlots,
                          Progress* progress)
{
    const std::vector<std::int32_t>& region = regions.region;
    const std::size_t regionCount = static_cast<std::size_t>(regions.count);
    std::vector<std::uint8_t> touched(regionCount, 0);
    for (Slot s : removedSlots) touched[region[s]] = 1;
    std::vector<Slot> kept;  // the kept voxels of the touched regions, in slot order
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (region[s] >= 0 && touched[region[s]] && !removed[s]) kept.push_back(s);
    // Each touched region's kept voxels, split into their connected parts: nodes from
    // regionCount on (the touched regions' own ids stay unused).
    std::unordered_map<Slot, std::int32_t> part;
    part.reserve(kept.size());
    UnionFind<> uf(regionCount);
    std::vector<Slot> queue;
    for (Slot s : kept) {
        if (part.count(s)) continue;
        const auto node = static_cast<std::int32_t>(uf.parent.size());
        uf.parent.push_back(node);
        part.emplace(s, node);
        queue.assign(1, s);
        for (std::size_t head = 0; head < queue.size(); ++head) {
            if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
            index.forEachNeighbour(queue[head], [&](Slot t, int) {
                if (removed[t] || region[t] != region[s] || part.count(t)) return;
                part.emplace(t, node);
                queue.push_back(t);
            });
        }
    }
    for (Slot s : kept) {
        const std::int32_t node = part.at(s);
        index.forEachNeighbour(s, [&](Slot t, int) {
            if (removed[t] || region[t] == region[s]) return;
            uf.unite(node, touched[region[t]] ? part.at(t) : region[t]);
        });
    }
    for (const auto& [a, b] : touching)
        if (!touched[a] && !touched[b]) uf.unite(a, b);
    std::size_t count = 0;
    for (std::size_t i = 0; i < uf.parent.size(); ++i)
        if ((i >= regionCount || !touched[i]) && uf.find(static_cast<int>(i)) == static_cast<int>(i)) ++count;
    return count;
}

} // namespace flyover::contact_regions
