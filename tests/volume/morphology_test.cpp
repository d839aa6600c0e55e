// detail::dilateVoxels / erodeVoxels with 26 neighbours (volume/segment_tools.cpp: three 1D
// passes of a cube on the leaves' bit masks) against OpenVDB's dilateActiveValues /
// erodeActiveValues (NN_FACE_EDGE_VERTEX, IGNORE_TILES), which they replace: the same active
// voxels, voxel for voxel.
#include "volume/segment_tools.h"

#include <gtest/gtest.h>

#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>

#include <random>
#include <sstream>
#include <string>

namespace flyover {
namespace {

using openvdb::BoolTree;
using openvdb::Coord;

/// Random blobs and single voxels (some far apart, some crossing leaf borders, some at
/// negative coordinates), so that the passes meet missing neighbour leaves on every side.
BoolTree::Ptr randomSet(unsigned seed)
{
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> pos(-40, 60), radius(0, 9), coin(0, 9);
    auto tree = std::make_shared<BoolTree>(false);
    openvdb::tree::ValueAccessor<BoolTree> acc(*tree);
    for (int b = 0; b < 25; ++b) {
        const Coord c(pos(rng), pos(rng), pos(rng));
        const int r = radius(rng);
        for (int x = -r; x <= r; ++x)
            for (int y = -r; y <= r; ++y)
                for (int z = -r; z <= r; ++z)
                    if (x * x + y * y + z * z <= r * r && coin(rng) != 0) acc.setValueOn(c.offsetBy(x, y, z), true);
    }
    // A far-away lone voxel and a solid block whose leaves are full.
    acc.setValueOn(Coord(300, -200, 17), true);
    for (int x = 80; x < 104; ++x)
        for (int y = 0; y < 24; ++y)
            for (int z = -8; z < 16; ++z) acc.setValueOn(Coord(x, y, z), true);
    return tree;
}

/// The first voxels where the two trees' active states differ (empty when identical).
std::string differences(const BoolTree& expected, const BoolTree& seen)
{
    std::ostringstream out;
    int reported = 0;
    auto check = [&](const BoolTree& a, const BoolTree& b, const char* what) {
        openvdb::tree::ValueAccessor<const BoolTree> acc(b);
        for (auto it = a.cbeginValueOn(); it; ++it)
            if (!acc.isValueOn(it.getCoord()) && reported++ < 8) out << what << " " << it.getCoord() << "\n";
    };
    check(expected, seen, "active in OpenVDB's result, not in ours:");
    check(seen, expected, "active in ours, not in OpenVDB's:");
    if (expected.activeVoxelCount() != seen.activeVoxelCount())
        out << "active voxels: OpenVDB " << expected.activeVoxelCount() << ", ours " << seen.activeVoxelCount() << "\n";
    return out.str();
}

TEST(BoxMorphology, DilationEqualsOpenVdbs26NeighbourDilation)
{
    for (unsigned seed = 1; seed <= 3; ++seed)
        for (int iterations : {1, 2, 6, 9, 17, 30}) {
            const BoolTree::Ptr input = randomSet(seed);
            BoolTree expected(*input), seen(*input);
            openvdb::tools::dilateActiveValues(expected, iterations, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                               openvdb::tools::IGNORE_TILES);
            detail::dilateVoxels(seen, iterations, detail::Neighbours::All);
            EXPECT_EQ(differences(expected, seen), "") << "seed " << seed << ", " << iterations << " iterations";
            EXPECT_GT(seen.activeVoxelCount(), input->activeVoxelCount());
        }
}

TEST(BoxMorphology, ErosionEqualsOpenVdbs26NeighbourErosion)
{
    for (unsigned seed = 1; seed <= 3; ++seed)
        for (int iterations : {1, 2, 5, 7, 9}) {
            const BoolTree::Ptr input = randomSet(seed);
            BoolTree expected(*input), seen(*input);
            openvdb::tools::erodeActiveValues(expected, iterations, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                              openvdb::tools::IGNORE_TILES);
            openvdb::tools::pruneInactive(expected);
            detail::erodeVoxels(seen, iterations, detail::Neighbours::All);
            EXPECT_EQ(differences(expected, seen), "") << "seed " << seed << ", " << iterations << " iterations";
            EXPECT_LT(seen.activeVoxelCount(), input->activeVoxelCount());
            // The 24^3 block survives erosions of up to 11 steps: something is left.
            EXPECT_GT(seen.activeVoxelCount(), 0u) << iterations << " iterations";
        }
}

TEST(BoxMorphology, DilationKeepsTheValuesOfActiveVoxels)
{
    // OpenVDB's dilation changes the active states only: a voxel that held true still does, a
    // newly active voxel holds what it held (the background in a new leaf).
    BoolTree tree(false);
    tree.setValueOn(Coord(3, 3, 3), true);
    tree.setValueOff(Coord(4, 3, 3), true);
    detail::dilateVoxels(tree, 2, detail::Neighbours::All);
    EXPECT_TRUE(tree.getValue(Coord(3, 3, 3)));
    EXPECT_TRUE(tree.getValue(Coord(4, 3, 3)));
    EXPECT_TRUE(tree.isValueOn(Coord(4, 3, 3)));
    EXPECT_FALSE(tree.getValue(Coord(1, 1, 1)));
    EXPECT_TRUE(tree.isValueOn(Coord(1, 1, 1)));
    EXPECT_FALSE(tree.isValueOn(Coord(0, 3, 3)));
    EXPECT_EQ(tree.activeVoxelCount(), 125u);
}

} // namespace
} // namespace flyover
