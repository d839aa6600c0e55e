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

Regions lumenRegions(const LumenIndex& index, double voxelMm, double chunkMm, Progress* progress,
                     const FloodOptions& flood)
{
    const std::size_t n = index.slotCount();
    const std::size_t blocks = index.blockOrigin.size();
    // 1. Cores: the bit of every slot that is not a core voxel is set (SlotBits: a block's bits
    // in one cache line), so that the searches below find the core voxels not yet reached as
    // clear bits (forEachClearNeighbour).
    SlotBits notCore(blocks);
    {
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
    }
    reportProgress(progress, 0.15, "contacts: core chunks");

    // 2. Chunks: shells of breadth-first steps within each core piece, then connected parts of
    // each shell. A 26-step is up to sqrt(3) voxels long: shells count steps of ~1.2 voxels.
    // The queues carry the steps, the bits say what was reached: `shell` is the only per-slot
    // array read, once per core neighbour of a voxel of the same part.
    std::vector<std::int32_t> region(n, -1);
    std::int32_t regionCount = 0;
    {
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
        std::vector<std::pair<Slot, std::int32_t>>().swap(stepQueue);
        SlotBits labelled = std::move(notCore);  // and the core voxels labelled
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
    }
    reportProgress(progress, 0.3, "contacts: regions");

    // 3. Regions: priority flood by decreasing D. A voxel takes the region of the voxel that
    // reaches it first; buckets a quarter voxel wide; a voxel deeper than the current level
    // (rare: a non-core voxel behind a saddle) is processed at the current level.
    {
        float maxDepth = 0.0f;
        for (std::size_t s = 0; s < n; ++s) maxDepth = std::max(maxDepth, index.depthMm[s]);
        const double binMm = 0.25 * voxelMm;
        const int bins = static_cast<int>(maxDepth / binMm) + 1;
        auto binOf = [&](Slot s) {
            return std::min(bins - 1, static_cast<int>(double(index.depthMm[s]) / binMm));
        };
        // A bucket entry carries the region it floods, so that a voxel's own region is not
        // read back from `region` (a scattered read) when it is taken.
        struct Entry {
            Slot s;
            std::int32_t r;
        };
        std::vector<std::vector<Entry>> buckets(static_cast<std::size_t>(bins));
        for (Slot s = 0; s < n; ++s)
            if (region[s] >= 0) buckets[binOf(s)].push_back({s, region[s]});
        // Whether a slot is taken (a hole or already in a region): one bit per slot, a block's
        // 512 bits in one cache line, so that testing the 26 neighbours of a voxel reads at
        // most 8 lines (its block's and its neighbour blocks') instead of 26 scattered reads.
        // A lumen voxel not yet in a region holds its bin in `region` (UNREACHED - bin < 0), so
        // that taking it reads and writes one scattered value instead of its depth and its
        // region. The same flood, the same regions.
        constexpr std::int32_t UNREACHED = -3;
        SlotBits taken(blocks);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t blk = r.begin(); blk != r.end(); ++blk)
                for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s) {
                    if (region[s] >= 0 || !index.isLumen(s)) taken.set(s);
                    else region[s] = UNREACHED - binOf(s);
                }
        });
        // Large batches in two passes (contact_regions.h): the first lists, per task of
        // consecutive entries, the neighbours not taken when the batch began, each with the
        // region of the first of the task's entries to reach it and its bin (read from
        // `region` there, in parallel); the second takes them in the queue's order.
        struct Listed {
            Slot t;
            std::int32_t r;
            std::int32_t code;  ///< region[t] when listed: UNREACHED - its bin
        };
        const int threads = threadsThatMayRun();
        const std::size_t chunkEntries = std::max<std::size_t>(1, flood.chunkEntries);
        tbb::enumerable_thread_specific<SlotBits> listedBits([&] { return SlotBits(blocks); });
        std::vector<std::vector<Listed>> lists;
        tbb::enumerable_thread_specific<std::vector<Listed>> scratch;
        std::size_t done = 0;
        for (int b = bins - 1; b >= 0; --b) {
            std::vector<Entry>& bucket = buckets[b];
            std::size_t i = 0;
            while (i < bucket.size()) {  // grows while visited
                const std::size_t end = bucket.size();
                if (threads < 2 || end - i < std::max<std::size_t>(1, flood.minParallelBatch)) {
                    for (; i < end; ++i) {
                        if ((++done & 0xfffff) == 0) checkCancelled(progress);
                        const Entry e = bucket[i];
                        forEachClearNeighbour(index, taken, e.s, [&](Slot t) {
                            taken.set(t);
                            const int bin = UNREACHED - region[t];
                            region[t] = e.r;
                            buckets[std::min(b, bin)].push_back({t, e.r});
                        });
                    }
                    continue;
                }
                checkCancelled(progress);
                const std::size_t tasks = (end - i + chunkEntries - 1) / chunkEntries;
                if (lists.size() < tasks) lists.resize(tasks);
                tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tasks, 1),
                                  [&](const tbb::blocked_range<std::size_t>& r) {
                    SlotBits& mine = listedBits.local();
                    std::vector<Listed>& out = scratch.local();  // not lists[task]: no false sharing
                    for (std::size_t task = r.begin(); task != r.end(); ++task) {
                        out.clear();
                        const std::size_t from = i + task * chunkEntries, to = std::min(end, from + chunkEntries);
                        for (std::size_t j = from; j < to; ++j) {
                            const Entry e = bucket[j];
                            forEachClearNeighbour(index, taken, e.s, [&](Slot t) {
                                if (mine.testAndSet(t)) return;
                                out.push_back({t, e.r, region[t]});
                            });
                        }
                        for (const Listed& l : out) mine.reset(l.t);
                        lists[task].swap(out);
                    }
                });
                for (std::size_t task = 0; task < tasks; ++task)
                    for (const Listed& l : lists[task]) {
                        if (taken.testAndSet(l.t)) continue;
                        region[l.t] = l.r;
                        buckets[std::min(b, UNREACHED - l.code)].push_back({l.t, l.r});
                    }
                done += end - i;
                i = end;
            }
            std::vector<Entry>().swap(bucket);
        }
        // Lumen voxels left unreached (in pieces without core voxels) still hold their bin (< 0).
        // Pieces without any core voxel (too thin everywhere): one region each.
        labelUnreachedPieces(index, region, regionCount);
    }
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
