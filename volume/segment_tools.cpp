// The heavy OpenVDB tool families used by segmentation live in this translation unit only
// (style.md §4). All of them are pre-instantiated for the tree types used here. The fast
// sweeping redistance is in redistance.cpp.
#include "volume/segment_tools.h"

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>
#include <limits>

namespace flyover::detail {

void dilateVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours)
{
    if (iterations <= 0) return;
    openvdb::tools::dilateActiveValues(tree, iterations,
                                       neighbours == Neighbours::Face
                                           ? openvdb::tools::NN_FACE
                                           : openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::IGNORE_TILES);
}

void erodeVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours)
{
    if (iterations <= 0) return;
    openvdb::tools::erodeActiveValues(tree, iterations,
                                      neighbours == Neighbours::Face
                                          ? openvdb::tools::NN_FACE
                                          : openvdb::tools::NN_FACE_EDGE_VERTEX,
                                      openvdb::tools::IGNORE_TILES);
    openvdb::tools::pruneInactive(tree);
}

std::vector<openvdb::BoolTree::Ptr> connectedComponents(const openvdb::BoolTree& tree)
{
    // segmentActiveVoxels joins face neighbours only (6-connectivity).
    std::vector<openvdb::BoolTree::Ptr> segments;
    openvdb::tools::segmentActiveVoxels(tree, segments);  // sorted by voxel count, descending
    segments.erase(std::remove_if(segments.begin(), segments.end(),
                                  [](const openvdb::BoolTree::Ptr& t) { return !t || t->activeVoxelCount() == 0; }),
                   segments.end());
    return segments;
}

openvdb::BoolTree::Ptr reachableWithin(const openvdb::BoolTree& seed,
                                       const openvdb::BoolTree& allowed, int maxIterations)
{
    auto reach = std::make_shared<openvdb::BoolTree>(seed);
    openvdb::Index64 count = reach->activeVoxelCount();
    for (int i = 0; i < maxIterations; ++i) {
        dilateVoxels(*reach, 1, Neighbours::Face);
        reach->topologyIntersection(allowed);
        reach->topologyUnion(seed);
        const openvdb::Index64 now = reach->activeVoxelCount();
        if (now == count) break;
        count = now;
    }
    return reach;
}

void trimExteriorBand(openvdb::FloatTree& sdf, float bandMm)
{
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(sdf);
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it)
            if (!(*it <= bandMm)) leaf.setValueOff(it.pos(), bandMm);
    });
    openvdb::tools::changeLevelSetBackground(sdf, bandMm);
    openvdb::tools::pruneLevelSet(sdf);
}

void pruneInactive(openvdb::BoolTree& tree) { openvdb::tools::pruneInactive(tree); }
void pruneInactive(openvdb::FloatTree& tree) { openvdb::tools::pruneInactive(tree); }

} // namespace flyover::detail
