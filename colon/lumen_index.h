/// @file lumen_index.h
/// @brief A flat, leaf-blocked index of the lumen voxels (sdf < 0) of a sparse signed distance
///        grid, shared by the searches over the lumen (centerline.cpp, contacts.cpp): per-voxel
///        data lives in flat arrays and 26-neighbours are found by arithmetic.
///
/// What it does not do: it holds no grid; it copies D = -sdf once and never sees later edits.
#pragma once

#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cstdint>
#include <limits>
#include <type_traits>
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

    /// The slot of the voxel at leaf-local (nx, ny, nz), each in [-8, 15], of block `block`
    /// (a neighbouring leaf's when outside [0, 7]), or NO_SLOT where no block holds it.
    Slot slotAt(std::size_t block, int nx, int ny, int nz) const
    {
        // The arithmetic shift gives -1, 0 or +1 for the neighbouring leaf.
        const int b = neighbour[block][std::size_t(((nx >> LEAF_LOG2) + 1) * 9 + ((ny >> LEAF_LOG2) + 1) * 3 +
                                                   ((nz >> LEAF_LOG2) + 1))];
        if (b < 0) return NO_SLOT;
        return static_cast<Slot>(b) * LEAF_VOXELS +
               static_cast<Slot>(((nx & (LEAF_DIM - 1)) << (2 * LEAF_LOG2)) | ((ny & (LEAF_DIM - 1)) << LEAF_LOG2) |
                                 (nz & (LEAF_DIM - 1)));
    }

    /// The slot of the 26-neighbour of `s` one step STEPS[k] away (a lumen voxel or a hole), or
    /// NO_SLOT where no block holds it.
    Slot stepSlot(Slot s, int k) const
    {
        const int off = static_cast<int>(s % LEAF_VOXELS);
        const Step& st = STEPS[std::size_t(k)];
        return slotAt(s / LEAF_VOXELS, (off >> (2 * LEAF_LOG2)) + st.dx, ((off >> LEAF_LOG2) & (LEAF_DIM - 1)) + st.dy,
                      (off & (LEAF_DIM - 1)) + st.dz);
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
        for (int k = 0; k < 26; ++k) {
            const Step& st = STEPS[k];
            const Slot t = slotAt(block, x + STRIDE * st.dx, y + STRIDE * st.dy, z + STRIDE * st.dz);
            if (t == NO_SLOT) continue;
            fn(t, k);
        }
    }
};

/// One bit per slot of a LumenIndex, a block's 512 bits in one 64-byte cache line: testing a
/// voxel's 26 neighbours reads at most 8 lines.
class SlotBits {
public:
    explicit SlotBits(std::size_t blocks) : lines_(blocks) {}
    bool test(Slot s) const { return (word(s) >> (s & 63)) & 1u; }
    void set(Slot s) { word(s) |= std::uint64_t(1) << (s & 63); }
    void reset(Slot s) { word(s) &= ~(std::uint64_t(1) << (s & 63)); }
    /// Sets the bit; returns whether it was set before.
    bool testAndSet(Slot s)
    {
        std::uint64_t& w = word(s);
        const std::uint64_t bit = std::uint64_t(1) << (s & 63);
        const bool was = (w & bit) != 0;
        w |= bit;
        return was;
    }

    /// The 8 words of a block's bits: word x holds the voxels (x, y, z) at bit y * 8 + z.
    const std::uint64_t* blockWords(std::size_t block) const { return lines_[block].words; }
    std::uint64_t* blockWords(std::size_t block) { return lines_[block].words; }

private:
    struct alignas(64) Line {
        std::uint64_t words[LEAF_VOXELS / 64] = {};
    };
    static_assert(sizeof(Line) == 64, "a block's bits are one cache line");
    static constexpr int BLOCK = LEAF_VOXELS;
    std::uint64_t& word(Slot s) { return lines_[s / BLOCK].words[(s % BLOCK) >> 6]; }
    const std::uint64_t& word(Slot s) const { return lines_[s / BLOCK].words[(s % BLOCK) >> 6]; }
    std::vector<Line> lines_;
};

/// The index in STEPS of the step (dx, dy, dz), each in {-1, 0, 1}, not all 0.
constexpr int stepIndex(int dx, int dy, int dz)
{
    const int i = (dx + 1) * 9 + (dy + 1) * 3 + (dz + 1);
    return i > 13 ? i - 1 : i;  // 13: (0, 0, 0), not a step
}

/// Calls fn(t) -- or fn(t, stepIndex) when fn takes two arguments -- for each 26-neighbour
/// slot t of `s` whose bit in `bits` is clear, in LumenIndex::forEachNeighbourSlot's order. For a voxel whose neighbours all lie in its block,
/// the clear bits of each of the three x-slices' 3x3 windows are read as one masked word (the
/// window's bits in increasing (y, z) order, the steps' order); for one whose z-neighbours lie
/// in its block, each (dx, dy) row's three bits as one masked word; fn may set t's bit.
template <typename Fn>
void forEachClearNeighbour(const LumenIndex& index, const SlotBits& bits, Slot s, Fn&& fn)
{
    auto call = [&fn](Slot t, int k) {
        if constexpr (std::is_invocable_v<Fn&, Slot, int>) fn(t, k);
        else fn(t);
    };
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
                call(base + static_cast<Slot>((x + dx) * 64 + pos), stepIndex(dx, (pos >> 3) - y, (pos & 7) - z));
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
                    call(row + static_cast<Slot>(pos), stepIndex(dx, dy, pos - 1));
                }
            }
        }
        return;
    }
    index.forEachNeighbourSlot(s, [&](Slot t, int k) {
        if (!bits.test(t)) call(t, k);
    });
}

/// Bits set at the slots s of `index` for which pred(s), filled in parallel over blocks.
template <typename Pred>
SlotBits bitsWhere(const LumenIndex& index, Pred&& pred)
{
    const std::size_t blocks = index.blockOrigin.size();
    SlotBits bits(blocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t blk = r.begin(); blk != r.end(); ++blk)
            for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s)
                if (pred(s)) bits.set(s);
    });
    return bits;
}

/// Bits set at the index's holes (its slots of no lumen voxel): where a search over the lumen
/// with forEachClearNeighbour starts.
inline SlotBits holeBits(const LumenIndex& index)
{
    return bitsWhere(index, [&](Slot s) { return !index.isLumen(s); });
}

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
