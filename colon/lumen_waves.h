/// @file lumen_waves.h
/// @brief Breadth-first search over a LumenIndex a layer at a time, a block's voxels as 512 bits:
///        the next layer is the current one dilated by the 26-neighbourhood (three separable
///        one-voxel dilations along z, y and x, carried into the neighbouring blocks at the
///        faces) less what is reached. The steps of every voxel are those of a queue-driven
///        breadth-first search; only the order within a layer is lost (callers that need a
///        voxel of the last layer take the lowest slot). A few word operations per block of the
///        front instead of a queue entry and 26 bit tests per voxel.
///
/// What it does not do: it keeps no per-voxel data; the caller's onLayer does.
#pragma once

#include "colon/lumen_index.h"

#include <cstdint>
#include <limits>
#include <vector>

namespace flyover::lumen_index {

/// A block's 512 bits (word x: the voxels (x, y, z) at bit y * 8 + z, as SlotBits).
struct BlockWords {
    std::uint64_t w[LEAF_VOXELS / 64] = {};
    bool any() const
    {
        std::uint64_t o = 0;
        for (std::uint64_t v : w) o |= v;
        return o != 0;
    }
};

/// Calls fn(slot) for every bit set in `words`, block `block`'s, in increasing slot order.
template<typename Fn>
void forEachSlot(std::uint32_t block, const BlockWords& words, Fn&& fn)
{
    const Slot base = static_cast<Slot>(block) * LEAF_VOXELS;
    for (int x = 0; x < LEAF_VOXELS / 64; ++x)
        for (std::uint64_t v = words.w[x]; v; v &= v - 1)
            fn(base + static_cast<Slot>(x * 64 + __builtin_ctzll(v)));
}

/// A sparse set of blocks' words: the blocks touched, in the order first touched, and a dense
/// per-block position (-1: untouched) for the lookup.
class BlockSet {
public:
    explicit BlockSet(std::size_t blocks) : mPos(blocks, -1) {}
    BlockWords& at(std::uint32_t block)
    {
        std::int32_t& p = mPos[block];
        if (p < 0) {
            p = static_cast<std::int32_t>(mBlocks.size());
            mBlocks.push_back(block);
            mWords.emplace_back();
        }
        return mWords[std::size_t(p)];
    }
    std::size_t size() const { return mBlocks.size(); }
    std::uint32_t block(std::size_t i) const { return mBlocks[i]; }
    const BlockWords& words(std::size_t i) const { return mWords[i]; }
    void clear()
    {
        for (std::uint32_t b : mBlocks) mPos[b] = -1;
        mBlocks.clear();
        mWords.clear();
    }

private:
    std::vector<std::int32_t> mPos;
    std::vector<std::uint32_t> mBlocks;
    std::vector<BlockWords> mWords;
};

/// What a search reached: its last layer (-1: nothing) and the lowest slot in it.
struct WaveEnd {
    std::int32_t layer = -1;
    Slot lowestInLast = NO_SLOT;
};

/// The layered search's scratch, kept across searches over one index.
class LumenWaves {
public:
    explicit LumenWaves(const LumenIndex& index);

    /// Breadth-first from `seeds` over the slots whose bit in `reached` is clear (set them
    /// there as they are reached; holes must be set), at most maxLayer layers deep. Calls
    /// onLayer(layer, block, words) for every block with voxels first reached in `layer`
    /// (seeds: layer 0), layer by layer; blocks within a layer in no defined order.
    template<typename OnLayer>
    WaveEnd run(SlotBits& reached, const std::vector<Slot>& seeds, OnLayer&& onLayer, Progress* progress,
                std::int32_t maxLayer = std::numeric_limits<std::int32_t>::max());

private:
    /// mFront dilated by one 26-neighbour step, less `reached`, set in `reached`: the next
    /// front. Each block of the front is dilated into its own 3x3x3 blocks (so that a diagonal
    /// step through a block the index lacks is still taken), which its neighbour table names.
    void advance(SlotBits& reached);

    const LumenIndex& mIndex;
    BlockSet mFront, mNext;
};

template<typename OnLayer>
WaveEnd LumenWaves::run(SlotBits& reached, const std::vector<Slot>& seeds, OnLayer&& onLayer, Progress* progress,
                        std::int32_t maxLayer)
{
    mFront.clear();
    for (Slot s : seeds)
        if (!reached.testAndSet(s)) mFront.at(s / LEAF_VOXELS).w[(s % LEAF_VOXELS) >> 6] |= std::uint64_t(1) << (s & 63);
    WaveEnd end;
    for (std::int32_t layer = 0; mFront.size() > 0; ++layer) {
        if ((layer & 63) == 63) checkCancelled(progress);
        Slot lowest = NO_SLOT;
        for (std::size_t i = 0; i < mFront.size(); ++i) {
            const std::uint32_t b = mFront.block(i);
            const BlockWords& words = mFront.words(i);
            onLayer(layer, b, words);
            for (int x = 0; x < LEAF_VOXELS / 64; ++x)
                if (words.w[x]) {
                    const Slot s = static_cast<Slot>(b) * LEAF_VOXELS + static_cast<Slot>(x * 64 + __builtin_ctzll(words.w[x]));
                    if (s < lowest) lowest = s;
                    break;
                }
        }
        end.layer = layer;
        end.lowestInLast = lowest;
        if (layer == maxLayer) break;
        advance(reached);
    }
    return end;
}

} // namespace flyover::lumen_index
