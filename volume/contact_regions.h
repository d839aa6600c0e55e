/// @file contact_regions.h
/// @brief Steps 1-3 of the contact search (contacts.h): the lumen's cores, their chunks and
///        the regions flooded from them by decreasing depth. Internal to cutContacts; its own
///        unit so that tests can compare it with a plain reference flood.
///
/// What it does not do: it builds no region graph and cuts nothing (contacts.cpp does).
#pragma once

#include "volume/lumen_index.h"
#include "volume/progress.h"
#include "volume/union_find.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

namespace flyover::contact_regions {

/// One bit per slot of a LumenIndex, a block's 512 bits in one 64-byte cache line: testing a
/// voxel's 26 neighbours reads at most 8 lines.
class SlotBits {
public:
    explicit SlotBits(std::size_t blocks) : lines_(blocks) {}
    bool test(lumen_index::Slot s) const { return (word(s) >> (s & 63)) & 1u; }
    void set(lumen_index::Slot s) { word(s) |= std::uint64_t(1) << (s & 63); }
    void reset(lumen_index::Slot s) { word(s) &= ~(std::uint64_t(1) << (s & 63)); }
    /// Sets the bit; returns whether it was set before.
    bool testAndSet(lumen_index::Slot s)
    {
        std::uint64_t& w = word(s);
        const std::uint64_t bit = std::uint64_t(1) << (s & 63);
        const bool was = (w & bit) != 0;
        w |= bit;
        return was;
    }

    /// The 8 words of a block's bits: word x holds the voxels (x, y, z) at bit y * 8 + z.
    const std::uint64_t* blockWords(std::size_t block) const { return lines_[block].words; }

private:
    struct alignas(64) Line {
        std::uint64_t words[lumen_index::LEAF_VOXELS / 64] = {};
    };
    static_assert(sizeof(Line) == 64, "a block's bits are one cache line");
    static constexpr int BLOCK = lumen_index::LEAF_VOXELS;
    std::uint64_t& word(lumen_index::Slot s) { return lines_[s / BLOCK].words[(s % BLOCK) >> 6]; }
    const std::uint64_t& word(lumen_index::Slot s) const { return lines_[s / BLOCK].words[(s % BLOCK) >> 6]; }
    std::vector<Line> lines_;
};

/// How the flood (lumenRegions, step 3) shares its work between threads; the regions are the
/// same for any values and any number of threads.
struct FloodOptions {
    /// A batch of queue entries this large or larger is taken in two passes (see lumenRegions)
    /// when more than one thread may run; smaller ones one entry at a time.
    std::size_t minParallelBatch = 8192;
    /// Entries per task of the first pass.
    std::size_t chunkEntries = 2048;
};

/// Calls fn(t) for each 26-neighbour slot t of `s` whose bit in `bits` is clear, in
/// LumenIndex::forEachNeighbourSlot's order. For a voxel whose neighbours all lie in its block,
/// the clear bits of each of the three x-slices' 3x3 windows are read as one masked word (the
/// window's bits in increasing (y, z) order, the steps' order); for one whose z-neighbours lie
/// in its block, each (dx, dy) row's three bits as one masked word; fn may set t's bit.
template <typename Fn>
void forEachClearNeighbour(const lumen_index::LumenIndex& index, const SlotBits& bits, lumen_index::Slot s, Fn&& fn)
{
    using namespace lumen_index;
    const int off = static_cast<int>(s % LEAF_VOXELS);
    const int x = off >> (2 * LEAF_LOG2), y = (off >> LEAF_LOG2) & (LEAF_DIM - 1), z = off & (LEAF_DIM - 1);
    if (x >= 1 && x <= LEAF_DIM - 2 && y >= 1 && y <= LEAF_DIM - 2 && z >= 1 && z <= LEAF_DIM - 2) {
        static_assert(LEAF_DIM == 8, "a block's x-slice is one 64-bit word");
        const std::uint64_t* words = bits.blockWords(s / LEAF_VOXELS);
        const std::uint64_t window = std::uint64_t(0x070707) << ((y - 1) * 8 + (z - 1));
        const std::uint64_t centre = std::uint64_t(1) << (y * 8 + z);
        const Slot base = s - static_cast<Slot>(off);
        for (int dx = -1; dx <= 1; ++dx) {
            std::uint64_t clear = ~words[x + dx] & window & (dx == 0 ? ~centre : ~std::uint64_t(0));
            while (clear) {
                const int pos = __builtin_ctzll(clear);
                clear &= clear - 1;
                fn(base + static_cast<Slot>((x + dx) * 64 + pos));
            }
        }
        return;
    }
    if (z >= 1 && z <= LEAF_DIM - 2) {
        // Neighbours in other blocks along x or y only: per (dx, dy), the three z-neighbours'
        // bits from one word of that row's block.
        const auto& nb = index.neighbour[s / LEAF_VOXELS];
        for (int dx = -1; dx <= 1; ++dx) {
            const int nx = x + dx;
            for (int dy = -1; dy <= 1; ++dy) {
                const int ny = y + dy;
                const std::int32_t b = nb[((nx >> LEAF_LOG2) + 1) * 9 + ((ny >> LEAF_LOG2) + 1) * 3 + 1];
                if (b < 0) continue;
                const int lx = nx & (LEAF_DIM - 1), ly = ny & (LEAF_DIM - 1);
                const int first = ly * 8 + z - 1;
                std::uint64_t clear = (~bits.blockWords(static_cast<std::size_t>(b))[lx] >> first) & 7u;
                if (dx == 0 && dy == 0) clear &= ~std::uint64_t(2);  // the voxel itself
                const Slot row = static_cast<Slot>(b) * LEAF_VOXELS + static_cast<Slot>(lx * 64 + first);
                while (clear) {
                    const int pos = __builtin_ctzll(clear);
                    clear &= clear - 1;
                    fn(row + static_cast<Slot>(pos));
                }
            }
        }
        return;
    }
    index.forEachNeighbourSlot(s, [&](Slot t, int) {
        if (!bits.test(t)) fn(t);
    });
}

struct Regions {
    std::vector<std::int32_t> region;  ///< per slot: the region id, -1 for holes (non-lumen slots)
    std::int32_t count = 0;            ///< region ids are 0 .. count-1
};

/// 1. Cores: lumen voxels with D >= voxelMm and D >= half the largest D of their block and its
///    neighbour blocks. 2. Chunks: breadth-first shells of ~chunkMm (26-steps counted as 1.2
///    voxels) within each 26-connected core piece, split into connected parts: one region
///    each, numbered in slot order of their first voxel. 3. Every other lumen voxel takes the
///    region of the voxel that reaches it first in a priority flood by decreasing D (buckets a
///    quarter voxel wide, first in first out; a voxel deeper than the current bucket is taken
///    at the current one); pieces with no core voxel are one region each.
///    The queue of a bucket is taken in batches: the entries queued when the batch begins. A
///    large batch is taken in two passes: in parallel, each entry lists the neighbours not taken
///    when the batch began (each listed once per task, at its first entry); then, in the
///    queue's order, each listed voxel not taken since goes to the entry that listed it. That is
///    the entry that reaches it first in the queue's order, as in the one-by-one flood: the
///    same regions on any number of threads.
/// @throw Cancelled when progress asks
Regions lumenRegions(const lumen_index::LumenIndex& index, double voxelMm, double chunkMm,
                     Progress* progress = nullptr, const FloodOptions& flood = {});

/// Step 3's end: every lumen slot whose region is still < 0 (not reached by the flood: a
/// piece with no core voxel) takes a new id (from `count` on), one per 26-connected piece of
/// such slots, numbered in slot order of their first voxel.
void labelUnreachedPieces(const lumen_index::LumenIndex& index, std::vector<std::int32_t>& region,
                          std::int32_t& count);

/// The number of 26-connected pieces of the lumen without the voxels with removed[slot] != 0,
/// given its regions (lumenRegions), every pair of regions with 26-neighbouring voxels
/// (`touching`, any order, repeats allowed) and the removed slots (`removedSlots`, repeats
/// allowed; removed has one entry per slot). A region is 26-connected and meets another
/// exactly where they touch, so a region without a removed voxel is one node joined to its
/// touching regions; only the kept voxels of the regions holding a removed voxel are searched.
/// The same count as a search of the whole lumen, for the cost of those regions.
/// @throw Cancelled when progress asks
std::size_t piecesWithout(const lumen_index::LumenIndex& index, const Regions& regions,
                          const std::vector<std::pair<std::int32_t, std::int32_t>>& touching,
                          const std::vector<std::uint8_t>& removed,
                          const std::vector<lumen_index::Slot>& removedSlots, Progress* progress = nullptr);

} // namespace flyover::contact_regions
