/// @file contact_regions.h
/// @brief Steps 1-3 of the contact search (contacts.h): the lumen's cores, their chunks and
///        the regions flooded from them by decreasing depth. Internal to cutContacts; its own
///        unit so that tests can compare it with a plain reference flood.
///
/// What it does not do: it builds no region graph and cuts nothing (contacts.cpp does).
#pragma once

#include "volume/lumen_index.h"
#include "volume/progress.h"

#include <cstdint>
#include <vector>

namespace flyover::contact_regions {

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

} // namespace flyover::contact_regions
