#include "colon/lumen_waves.h"

namespace flyover::lumen_index {

LumenWaves::LumenWaves(const LumenIndex& index)
    : mIndex(index), mFront(index.blockOrigin.size()), mNext(index.blockOrigin.size())
{
}

namespace {

constexpr int WORDS = LEAF_VOXELS / 64;
constexpr std::uint64_t Z0 = 0x0101010101010101ull;  // the voxels at z = 0
constexpr std::uint64_t Z7 = Z0 << 7;                // at z = 7

/// A block's 3x3x3 neighbourhood of blocks, cell (cx, cy, cz) for the offsets cx - 1 ...
struct Neighbourhood {
    BlockWords cell[3][3][3];
};

} // namespace

void LumenWaves::advance(SlotBits& reached)
{
    mNext.clear();
    Neighbourhood n;
    for (std::size_t i = 0; i < mFront.size(); ++i) {
        const std::uint32_t b = mFront.block(i);
        const BlockWords& f = mFront.words(i);
        n = Neighbourhood{};
        // z: within the words, and the faces' bits into the blocks below and above.
        for (int x = 0; x < WORDS; ++x) {
            const std::uint64_t v = f.w[x];
            n.cell[1][1][1].w[x] = v | ((v << 1) & ~Z0) | ((v >> 1) & ~Z7);
            n.cell[1][1][2].w[x] = (v & Z7) >> 7;
            n.cell[1][1][0].w[x] = (v & Z0) << 7;
        }
        // y: rows of 8 bits.
        for (int cz = 0; cz < 3; ++cz)
            for (int x = 0; x < WORDS; ++x) {
                const std::uint64_t v = n.cell[1][1][cz].w[x];
                n.cell[1][1][cz].w[x] = v | (v << 8) | (v >> 8);
                n.cell[1][2][cz].w[x] = v >> 56;
                n.cell[1][0][cz].w[x] = v << 56;
            }
        // x: whole words.
        for (int cy = 0; cy < 3; ++cy)
            for (int cz = 0; cz < 3; ++cz) {
                const BlockWords e = n.cell[1][cy][cz];
                BlockWords& out = n.cell[1][cy][cz];
                for (int x = 0; x < WORDS; ++x)
                    out.w[x] = e.w[x] | (x > 0 ? e.w[x - 1] : 0) | (x < WORDS - 1 ? e.w[x + 1] : 0);
                n.cell[2][cy][cz].w[0] = e.w[WORDS - 1];
                n.cell[0][cy][cz].w[WORDS - 1] = e.w[0];
            }
        const auto& table = mIndex.neighbour[b];
        for (int cx = 0; cx < 3; ++cx)
            for (int cy = 0; cy < 3; ++cy)
                for (int cz = 0; cz < 3; ++cz) {
                    const BlockWords& c = n.cell[cx][cy][cz];
                    if (!c.any()) continue;
                    const std::int32_t t = table[std::size_t(cx * 9 + cy * 3 + cz)];
                    if (t < 0) continue;  // no lumen there
                    BlockWords& dst = mNext.at(static_cast<std::uint32_t>(t));
                    for (int x = 0; x < WORDS; ++x) dst.w[x] |= c.w[x];
                }
    }
    mFront.clear();
    for (std::size_t i = 0; i < mNext.size(); ++i) {
        const std::uint32_t b = mNext.block(i);
        std::uint64_t* r = reached.blockWords(b);
        BlockWords fresh;
        for (int x = 0; x < WORDS; ++x) {
            fresh.w[x] = mNext.words(i).w[x] & ~r[x];
            r[x] |= fresh.w[x];
        }
        if (fresh.any()) mFront.at(b) = fresh;
    }
}

} // namespace flyover::lumen_index
