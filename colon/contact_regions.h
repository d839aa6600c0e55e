/// @file contact_regions.h
/// @brief Steps 1-3 of the contact search (contacts.h): the lumen's cores, their chunks and
///        the regions flooded from them by decreasing depth. Internal to cutContacts; its own
///        unit so that tests can compare it with a plain reference flood.
///
/// What it does not do: it builds no region graph and cuts nothing (contacts.cpp does).
#pragma once

#include "colon/lumen_index.h"
#include "volume/progress.h"
#include "volume/union_find.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

namespace flyover::contact_regions {

using lumen_index::forEachClearNeighbour;
using lumen_index::SlotBits;

/// How the flood (lumenRegions, step 3) shares its work between threads; the regions are the
/// same for any values and any number of threads.
struct FloodOptions {
    /// A batch of queue entries this large or larger is taken in two passes (see lumenRegions)
    /// when more than one thread may run; smaller ones one entry at a time.
    std::size_t minParallelBatch = 8192;
    /// Entries per task of the first pass.
    std::size_t chunkEntries = 2048;
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
