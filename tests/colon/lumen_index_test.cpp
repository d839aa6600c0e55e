// The lumen index's neighbour walks (colon/lumen_index.h): forEachClearNeighbour, which reads
// a block's bits as masked words, against forEachNeighbourSlot filtered by the same bits: the
// same neighbours in the same order, with the same step index, for voxels inside a block, on
// its faces, edges and corners, and for random bits.
#include "colon/lumen_index.h"

#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include <random>
#include <utility>
#include <vector>

namespace flyover {
namespace {

using namespace lumen_index;

TEST(LumenIndex, ClearNeighboursAreTheFilteredNeighbourSlotsInTheirOrderWithTheirSteps)
{
    // A lumen spanning several blocks each way, with holes, so that every case of the walk
    // (inside a block, z inside, the rest) meets missing neighbour blocks too.
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    auto grid = openvdb::FloatGrid::create(3.0f);
    auto acc = grid->getAccessor();
    for (int i = -3; i < 21; ++i)
        for (int j = -3; j < 21; ++j)
            for (int k = -3; k < 13; ++k)
                if (u(rng) < 0.8) acc.setValue(openvdb::Coord(i, j, k), -1.0f);
    const LumenIndex index = buildIndex(grid->tree());
    const std::size_t blocks = index.blockOrigin.size();
    ASSERT_GT(blocks, 8u);
    for (double density : {0.0, 0.3, 0.9}) {
        SlotBits bits = holeBits(index);
        for (Slot s = 0; s < index.slotCount(); ++s) {
            EXPECT_EQ(bits.test(s), !index.isLumen(s)) << "holeBits at slot " << s;
            if (u(rng) < density) bits.set(s);
        }
        std::size_t walks = 0;
        for (Slot s = 0; s < index.slotCount(); ++s) {
            if (!index.isLumen(s)) continue;
            std::vector<std::pair<Slot, int>> expected, seen, seenOneArg;
            index.forEachNeighbourSlot(s, [&](Slot t, int k) {
                if (!bits.test(t)) expected.push_back({t, k});
            });
            forEachClearNeighbour(index, bits, s, [&](Slot t, int k) { seen.push_back({t, k}); });
            forEachClearNeighbour(index, bits, s, [&](Slot t) { seenOneArg.push_back({t, -1}); });
            ASSERT_EQ(seen, expected) << "slot " << s << " at " << index.coord(s) << ", bit density " << density;
            ASSERT_EQ(seenOneArg.size(), expected.size()) << "slot " << s;
            for (std::size_t i = 0; i < expected.size(); ++i) ASSERT_EQ(seenOneArg[i].first, expected[i].first);
            ++walks;
        }
        EXPECT_GT(walks, 1000u);
    }
    for (int k = 0; k < 26; ++k)
        EXPECT_EQ(stepIndex(STEPS[k].dx, STEPS[k].dy, STEPS[k].dz), k) << "step " << k;
}

} // namespace
} // namespace flyover
