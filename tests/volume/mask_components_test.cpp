// The face-connected components of a mask (volume/mask_components.h), against OpenVDB's
// segmentation of the same masks.
#include "volume/mask_components.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/Prune.h>

#include <random>
#include <set>
#include <sstream>
#include <tuple>
#include <vector>

using namespace flyover;

namespace {

std::vector<openvdb::Coord> activeCoords(const openvdb::BoolTree& t)
{
    std::vector<openvdb::Coord> v;
    for (auto it = t.cbeginValueOn(); it; ++it) {
        if (it.isVoxelValue()) { v.push_back(it.getCoord()); continue; }
        openvdb::CoordBBox b;
        it.getBoundingBox(b);
        for (auto c = b.begin(); c; ++c) v.push_back(*c);
    }
    std::sort(v.begin(), v.end());
    return v;
}

/// A mask over `box`: a whole 128^3 tile ([0,127]^3, touching the box), random sparse voxels
/// in a column above it (`sparseP`, near the percolation threshold of 6-connectivity: many components,
/// some large and winding), a block of 8^3 tiles and leaves enclosed by a one-voxel shell of
/// inactive voxels, and voxels switched off at random (`holeP`) beside it.
openvdb::BoolTree::Ptr randomMask(const openvdb::CoordBBox& box, uint32_t seed, double holeP, double sparseP)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    openvdb::BoolTree::Ptr m(new openvdb::BoolTree(false));
    m->fill(box, true, true);  // tiles wherever a node fits, leaves at the box's ragged edge
    const openvdb::CoordBBox shell(openvdb::Coord(131, 19, 19), openvdb::Coord(149, 61, 61));
    for (auto c = box.begin(); c; ++c) {
        const openvdb::Coord p = *c;
        if (p.z() > 128) {  // (a BoolTree per component costs ~0.6 MB: a few hundred of them)
            if (p.x() > 24 || p.y() > 24 || u(rng) >= sparseP) m->setValueOff(p);
        } else if (p.x() >= 128 || p.x() < 0) {
            const bool onShell = shell.isInside(p) && (p.x() == shell.min().x() || p.x() == shell.max().x() ||
                                                       p.y() == shell.min().y() || p.y() == shell.max().y() ||
                                                       p.z() == shell.min().z() || p.z() == shell.max().z());
            if (onShell || (p.y() > 80 && u(rng) < holeP)) m->setValueOff(p);
        }
    }
    openvdb::tools::pruneInactive(*m);
    return m;
}

} // namespace

TEST(MaskComponents, TouchingAndEnclosedEqualOpenVdbSegmentation)
{
    const openvdb::CoordBBox box(openvdb::Coord(-3, 0, 0), openvdb::Coord(152, 155, 150));
    for (const auto& [seed, holeP, sparseP] : {std::tuple{1u, 0.3, 0.30}, std::tuple{2u, 0.45, 0.25},
                                              std::tuple{3u, 0.55, 0.32}}) {
        SCOPED_TRACE("seed " + std::to_string(seed));
        const openvdb::BoolTree::Ptr mask = randomMask(box, seed, holeP, sparseP);
        ASSERT_EQ(mask->getValueDepth(openvdb::Coord(5, 5, 5)), 1) << "the test mask must hold a 128^3 tile";
        ASSERT_EQ(mask->getValueDepth(openvdb::Coord(140, 40, 40)), 2) << "and an enclosed 8^3 tile";
        std::vector<openvdb::BoolTree::Ptr> reference;
        openvdb::tools::extractActiveVoxelSegmentMasks(*mask, reference);
        std::set<std::vector<openvdb::Coord>> refEnclosed;
        std::vector<openvdb::Coord> refTouching;
        for (const auto& comp : reference) {
            openvdb::CoordBBox cb;
            comp->evalActiveVoxelBoundingBox(cb);
            bool touches = false;
            for (int a = 0; a < 3; ++a) touches = touches || cb.min()[a] <= box.min()[a] || cb.max()[a] >= box.max()[a];
            std::vector<openvdb::Coord> v = activeCoords(*comp);
            if (touches) refTouching.insert(refTouching.end(), v.begin(), v.end());
            else refEnclosed.insert(std::move(v));
        }
        std::sort(refTouching.begin(), refTouching.end());
        ASSERT_GT(refEnclosed.size(), 100u) << "the test mask must have many enclosed components";

        const MaskComponents got = faceConnectedComponents(*mask, box);
        std::set<std::vector<openvdb::Coord>> gotEnclosed;
        for (const auto& comp : got.enclosed) gotEnclosed.insert(activeCoords(*comp));
        EXPECT_EQ(got.enclosed.size(), refEnclosed.size()) << "enclosed components: expected " << refEnclosed.size()
                                                           << " as OpenVDB's segmentation, got " << got.enclosed.size();
        EXPECT_TRUE(gotEnclosed == refEnclosed) << "the enclosed components differ from OpenVDB's segmentation";
        int shown = 0;
        for (const auto& comp : refEnclosed)
            if (!gotEnclosed.count(comp) && shown++ < 3) {
                std::ostringstream o;
                for (const auto& c : comp) o << " " << c;
                ADD_FAILURE() << "OpenVDB's enclosed component (" << comp.size() << " voxels) not found:" << o.str().substr(0, 300);
            }
        const std::vector<openvdb::Coord> touching = activeCoords(*got.touching);
        EXPECT_EQ(touching.size(), refTouching.size()) << "voxels of the components touching the box";
        EXPECT_TRUE(touching == refTouching) << "the touching components differ from OpenVDB's segmentation";
    }
}

TEST(MaskComponents, EachComponentEqualsOpenVdbSegmentationLargestFirst)
{
    const openvdb::CoordBBox box(openvdb::Coord(-3, 0, 0), openvdb::Coord(152, 155, 150));
    const openvdb::BoolTree::Ptr mask = randomMask(box, 4u, 0.5, 0.3);
    std::vector<openvdb::BoolTree::Ptr> reference;
    openvdb::tools::segmentActiveVoxels(*mask, reference);
    std::multiset<std::vector<openvdb::Coord>> expected;
    for (const auto& comp : reference) expected.insert(activeCoords(*comp));
    ASSERT_GT(expected.size(), 100u) << "the test mask must have many components";

    const std::vector<openvdb::BoolTree::Ptr> got = connectedComponents(*mask);
    std::multiset<std::vector<openvdb::Coord>> seen;
    for (std::size_t k = 0; k < got.size(); ++k) {
        EXPECT_FALSE(got[k]->hasActiveTiles()) << "component " << k << " holds active tiles; expected voxels only";
        if (k > 0) {
            EXPECT_GE(got[k - 1]->activeVoxelCount(), got[k]->activeVoxelCount())
                << "components " << k - 1 << " and " << k << " are not largest first";
        }
        seen.insert(activeCoords(*got[k]));
    }
    EXPECT_EQ(got.size(), expected.size()) << "components: expected " << expected.size() << " as OpenVDB's, got " << got.size();
    EXPECT_TRUE(seen == expected) << "the components differ from OpenVDB's segmentation";

    // equal counts come in a fixed order: the same from a copy of the mask built in another order
    openvdb::BoolTree copy(false);
    std::vector<openvdb::Coord> all = activeCoords(*mask);
    for (auto it = all.rbegin(); it != all.rend(); ++it) copy.setValueOn(*it, true);
    const std::vector<openvdb::BoolTree::Ptr> again = connectedComponents(copy);
    ASSERT_EQ(again.size(), got.size());
    for (std::size_t k = 0; k < got.size(); ++k)
        EXPECT_EQ(activeCoords(*again[k]), activeCoords(*got[k])) << "component " << k << " differs between two builds of one mask";
}

TEST(MaskComponents, ComponentsKeepTheInputValuesAndEmptyGivesNone)
{
    openvdb::BoolTree mask(false);
    mask.setValueOn(openvdb::Coord(0, 0, 0), true);
    mask.setValueOn(openvdb::Coord(0, 0, 1), false);  // active, value false: same component
    mask.setValueOn(openvdb::Coord(5, 5, 5), true);
    mask.setValueOn(openvdb::Coord(40, 0, 0), false);  // another leaf
    const std::vector<openvdb::BoolTree::Ptr> got = connectedComponents(mask);
    ASSERT_EQ(got.size(), 3u) << "three components expected";
    EXPECT_EQ(got[0]->activeVoxelCount(), 2u);
    EXPECT_TRUE(got[0]->getValue(openvdb::Coord(0, 0, 0)));
    EXPECT_FALSE(got[0]->getValue(openvdb::Coord(0, 0, 1))) << "the input's value false on an active voxel was not kept";
    EXPECT_TRUE(got[0]->isValueOn(openvdb::Coord(0, 0, 1)));
    EXPECT_TRUE(got[1]->isValueOn(openvdb::Coord(5, 5, 5))) << "equal counts: the component of the first leaf first";
    EXPECT_TRUE(got[2]->isValueOn(openvdb::Coord(40, 0, 0)));

    EXPECT_TRUE(connectedComponents(openvdb::BoolTree(false)).empty()) << "an empty mask has no components";
    openvdb::BoolTree tile(false);
    tile.fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(127)), true, true);
    const std::vector<openvdb::BoolTree::Ptr> whole = connectedComponents(tile);
    ASSERT_EQ(whole.size(), 1u);
    EXPECT_EQ(whole[0]->activeVoxelCount(), 128u * 128u * 128u);
    EXPECT_FALSE(whole[0]->hasActiveTiles()) << "a tile must come back as voxels";
}
