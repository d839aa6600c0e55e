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
    /// Sets the bit; returns whether it was set before.
    bool testAndSet(lumen_index::Slot s)
    {
        std::uint64_t& w = word(s);
        const std::uint64_t bit = std::uint64_t(1) << (s & 63);
        const bool was = (w & bit) != 0;
        w |= bit;
        return was;
    }

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
/// @throw Cancelled when progress asks
Regions lumenRegions(const lumen_index::LumenIndex& index, double voxelMm, double chunkMm,
                     Progress* progress = nullptr);

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
