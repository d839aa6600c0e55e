/// @file lumen_index.h
/// @brief A flat, leaf-blocked index of the lumen voxels (sdf < 0) of a sparse signed distance
///        grid, shared by the searches over the lumen (centerline.cpp, contacts.cpp): per-voxel
///        data lives in flat arrays and 26-neighbours are found by arithmetic.
///
/// What it does not do: it holds no grid; it copies D = -sdf once and never sees later edits.
#pragma once

#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <limits>
#include <vector>

namespace flyover::lumen_index {

using openvdb::Coord;
using openvdb::FloatTree;
using FloatLeaf = FloatTree::LeafNodeType;

constexpr int LEAF_LOG2 = 3;  // FloatTree leaves are 8^3
constexpr int LEAF_DIM = 1 << LEAF_LOG2;
constexpr int LEAF_VOXELS = LEAF_DIM * LEAF_DIM * LEAF_DIM;
static_assert(FloatLeaf::DIM == LEAF_DIM, "FloatTree leaves are expected to be 8^3");
static_assert(LEAF_DIM % 2 == 0, "leaf origins must have even coordinates for the coarse lattice");

using Slot = std::uint32_t;
constexpr Slot NO_SLOT = std::numeric_limits<Slot>::max();

/// The 26 neighbour offsets with their step lengths in voxels (1, sqrt2, sqrt3).
struct Step {
    int dx, dy, dz;
    double lengthVoxels;
};

/// The 26 steps in a fixed order (dx outermost, dz innermost).
extern const std::array<Step, 26> STEPS;

/// Flat, leaf-blocked index of the lumen voxels: every sdf leaf holding lumen voxels gets a
/// block of 512 slots (slot = block * 512 + leaf offset), so that per-voxel data lives in flat
/// arrays and a neighbour is found by arithmetic plus one table lookup per block instead of a
/// tree traversal. Slots of non-lumen voxels are holes (depth < 0); leaves of a tube are
/// typically half full, so the holes cost less than a hash map would.
struct LumenIndex {
    std::vector<Coord> blockOrigin;                      ///< index-space leaf origin per block
    std::vector<std::array<std::int32_t, 27>> neighbour;  ///< block of the (dx,dy,dz) leaf, or -1
    std::vector<float> depthMm;                          ///< D = -sdf (> 0) per slot; -1: not lumen

    std::size_t slotCount() const { return depthMm.size(); }
    bool isLumen(Slot s) const { return depthMm[s] >= 0.0f; }
    Coord coord(Slot s) const
    {
        const int off = static_cast<int>(s % LEAF_VOXELS);
        return blockOrigin[s / LEAF_VOXELS] +
               Coord(off >> (2 * LEAF_LOG2), (off >> LEAF_LOG2) & (LEAF_DIM - 1), off & (LEAF_DIM - 1));
    }

    /// Calls fn(neighbourSlot, stepIndex) for each 26-neighbour of `s` that is a lumen voxel;
    /// with STRIDE 2, for the neighbours two voxels away (the lattice of even coordinates).
    template<int STRIDE = 1, typename Fn>
    void forEachNeighbour(Slot s, Fn&& fn) const
    {
        forEachNeighbourSlot<STRIDE>(s, [&](Slot t, int k) {
            if (depthMm[t] >= 0.0f) fn(t, k);
        });
    }

    /// Calls fn(neighbourSlot, stepIndex) for each 26-neighbour of `s` that has a slot, lumen
    /// voxel or hole, in forEachNeighbour's order: for callers whose own per-slot data marks
    /// the holes (one array read instead of two).
    template<int STRIDE = 1, typename Fn>
    void forEachNeighbourSlot(Slot s, Fn&& fn) const
    {
        const std::size_t block = s / LEAF_VOXELS;
        const int off = static_cast<int>(s % LEAF_VOXELS);
        const int x = off >> (2 * LEAF_LOG2), y = (off >> LEAF_LOG2) & (LEAF_DIM - 1),
                  z = off & (LEAF_DIM - 1);
        // A voxel whose neighbours all lie in its own leaf (42% of them at stride 1): slots by
        // offset, no block lookup; the same neighbours in the same order.
        constexpr int LO = STRIDE, HI = LEAF_DIM - 1 - STRIDE;
        if (x >= LO && x <= HI && y >= LO && y <= HI && z >= LO && z <= HI) {
            for (int k = 0; k < 26; ++k) {
                const Step& st = STEPS[k];
                const Slot t = static_cast<Slot>(
                    static_cast<int>(s) +
                    STRIDE * (st.dx * LEAF_DIM * LEAF_DIM + st.dy * LEAF_DIM + st.dz));
                fn(t, k);
            }
            return;
        }
        const auto& nb = neighbour[block];
        for (int k = 0; k < 26; ++k) {
            const Step& st = STEPS[k];
            const int nx = x + STRIDE * st.dx, ny = y + STRIDE * st.dy, nz = z + STRIDE * st.dz;
            // nx in [-2, 9]: the arithmetic shift gives -1, 0 or +1 for the neighbouring leaf.
            const int b = nb[((nx >> LEAF_LOG2) + 1) * 9 + ((ny >> LEAF_LOG2) + 1) * 3 +
                             ((nz >> LEAF_LOG2) + 1)];
            if (b < 0) continue;
            const Slot t = static_cast<Slot>(b) * LEAF_VOXELS +
                           static_cast<Slot>(((nx & (LEAF_DIM - 1)) << (2 * LEAF_LOG2)) |
                                             ((ny & (LEAF_DIM - 1)) << LEAF_LOG2) |
                                             (nz & (LEAF_DIM - 1)));
            fn(t, k);
        }
    }
};

/// Indexes every active voxel of `sdf` whose value is negative.
/// @throw InputError when the lumen is too large for 32-bit slots
LumenIndex buildIndex(const FloatTree& sdf);

inline void checkCancelled(Progress* progress)
{
    if (progress && progress->cancelled()) throw Cancelled();
}

/// Per block, the largest D over the block and its 26 neighbouring blocks: the depth of the
/// lumen's middle near each voxel.
std::vector<float> nearbyMaxDepth(const LumenIndex& index);

} // namespace flyover::lumen_index
