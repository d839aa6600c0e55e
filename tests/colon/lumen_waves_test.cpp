// The layered breadth-first search (colon/lumen_waves.h) against a queue-driven one over the
// same lumen: the same steps for every voxel, the same voxels reached, the lowest slot of the
// last layer, a depth limit; on lumens with holes, several pieces, and voxels joined only
// diagonally across a leaf the index does not hold.
#include "colon/lumen_waves.h"

#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

namespace flyover {
namespace {

using namespace lumen_index;

/// Steps from `seeds` by a FIFO queue (-1: not reached).
std::vector<std::int32_t> queueSteps(const LumenIndex& index, const std::vector<Slot>& seeds)
{
    std::vector<std::int32_t> steps(index.slotCount(), -1);
    SlotBits reached = holeBits(index);
    std::vector<Slot> queue;
    for (Slot s : seeds)
        if (!reached.testAndSet(s)) {
            steps[s] = 0;
            queue.push_back(s);
        }
    for (std::size_t head = 0; head < queue.size(); ++head)
        forEachClearNeighbour(index, reached, queue[head], [&](Slot t) {
            reached.set(t);
            steps[t] = steps[queue[head]] + 1;
            queue.push_back(t);
        });
    return steps;
}

void expectSameSearch(const LumenIndex& index, const std::vector<Slot>& seeds, const char* what)
{
    const std::vector<std::int32_t> expected = queueSteps(index, seeds);
    std::vector<std::int32_t> seen(index.slotCount(), -1);
    SlotBits reached = holeBits(index);
    LumenWaves waves(index);
    std::int32_t lastLayer = -1;
    const WaveEnd end = waves.run(reached, seeds, [&](std::int32_t layer, std::uint32_t block, const BlockWords& w) {
        EXPECT_GE(layer, lastLayer) << what << ": layers out of order";
        lastLayer = layer;
        forEachSlot(block, w, [&](Slot s) {
            EXPECT_EQ(seen[s], -1) << what << ": slot " << s << " reached twice";
            seen[s] = layer;
        });
    }, nullptr);
    std::int32_t deepest = -1;
    Slot lowest = NO_SLOT;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        ASSERT_EQ(seen[s], expected[s]) << what << ": steps of slot " << s << " at " << index.coord(s);
        EXPECT_EQ(reached.test(s), expected[s] >= 0 || !index.isLumen(s)) << what << ": reached bit of slot " << s;
        if (expected[s] > deepest) {
            deepest = expected[s];
            lowest = s;
        }
    }
    EXPECT_EQ(end.layer, deepest) << what;
    EXPECT_EQ(end.lowestInLast, lowest) << what << ": expected the lowest slot of the last layer";
}

TEST(LumenWaves, StepsAreThoseOfAQueueSearchOnRandomLumens)
{
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (double density : {0.35, 0.6, 0.95}) {
        auto grid = openvdb::FloatGrid::create(3.0f);
        auto acc = grid->getAccessor();
        for (int i = -9; i < 23; ++i)
            for (int j = -9; j < 17; ++j)
                for (int k = -5; k < 19; ++k)
                    if (u(rng) < density) acc.setValue(openvdb::Coord(i, j, k), -1.0f);
        const LumenIndex index = buildIndex(grid->tree());
        ASSERT_GT(index.blockOrigin.size(), 8u);
        std::vector<Slot> lumen;
        for (Slot s = 0; s < index.slotCount(); ++s)
            if (index.isLumen(s)) lumen.push_back(s);
        for (int trial = 0; trial < 3; ++trial) {
            std::vector<Slot> seeds;
            for (int k = 0; k <= trial * 2; ++k) seeds.push_back(lumen[std::size_t(u(rng) * double(lumen.size()))]);
            seeds.push_back(seeds.front());  // a repeated seed is reached once
            expectSameSearch(index, seeds, "random lumen");
        }
    }
}

TEST(LumenWaves, StepsDiagonallyAcrossALeafTheIndexLacks)
{
    // Two voxels touching only at a corner, in leaves (0,0,0) and (8,8,8): every other leaf
    // around the corner is absent from the index, yet the 26-neighbour step joins them.
    auto grid = openvdb::FloatGrid::create(3.0f);
    auto acc = grid->getAccessor();
    acc.setValue(openvdb::Coord(6, 6, 6), -1.0f);
    acc.setValue(openvdb::Coord(7, 7, 7), -1.0f);
    acc.setValue(openvdb::Coord(8, 8, 8), -1.0f);
    acc.setValue(openvdb::Coord(9, 8, 8), -1.0f);
    acc.setValue(openvdb::Coord(7, 0, 0), -1.0f);  // its own piece
    const LumenIndex index = buildIndex(grid->tree());
    ASSERT_EQ(index.blockOrigin.size(), 2u);
    Slot first = NO_SLOT;
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (index.isLumen(s) && index.coord(s) == openvdb::Coord(6, 6, 6)) first = s;
    ASSERT_NE(first, NO_SLOT);
    expectSameSearch(index, {first}, "diagonal corner");
    std::vector<std::int32_t> steps = queueSteps(index, {first});
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (index.isLumen(s) && index.coord(s) == openvdb::Coord(9, 8, 8)) {
            EXPECT_EQ(steps[s], 3) << "expected (9, 8, 8) three steps from (6, 6, 6)";
        }
}

TEST(LumenWaves, StopsAtItsDepthLimit)
{
    auto grid = openvdb::FloatGrid::create(3.0f);
    auto acc = grid->getAccessor();
    for (int i = 0; i < 40; ++i) acc.setValue(openvdb::Coord(i, 0, 0), -1.0f);
    const LumenIndex index = buildIndex(grid->tree());
    Slot first = NO_SLOT;
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (index.isLumen(s) && index.coord(s) == openvdb::Coord(0, 0, 0)) first = s;
    SlotBits reached = holeBits(index);
    LumenWaves waves(index);
    std::size_t count = 0;
    const WaveEnd end = waves.run(reached, {first}, [&](std::int32_t, std::uint32_t block, const BlockWords& w) {
        forEachSlot(block, w, [&](Slot) { ++count; });
    }, nullptr, 10);
    EXPECT_EQ(end.layer, 10);
    EXPECT_EQ(count, 11u) << "expected the voxels 0 to 10 steps from the seed";
    EXPECT_EQ(index.coord(end.lowestInLast), openvdb::Coord(10, 0, 0));
}

} // namespace
} // namespace flyover
