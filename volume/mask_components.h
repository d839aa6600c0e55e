/// @file mask_components.h
/// @brief The face-connected (6-connected) components of a mask: each its own tree, or split by
///        whether they touch a box's faces (the part analysis's air: outside air and voids).
#pragma once

#include <openvdb/openvdb.h>

#include <vector>

namespace flyover {

/// The face-connected components of a tree's active voxels (leaf voxels and active tiles),
/// each its own tree holding the input's values on its voxels (tiles become voxels), sorted by
/// voxel count, largest first (equal counts in the order of their first leaf); never returns a
/// tree without active voxels. The same union-find as faceConnectedComponents below.
std::vector<openvdb::BoolTree::Ptr> connectedComponents(const openvdb::BoolTree& tree);

/// The face-connected components of a mask's active voxels (leaf voxels and active tiles),
/// split by whether they touch a face of `box` (the mask lies within `box`).
/// A union-find over the components within each leaf and over the active tiles, joined
/// across leaf and tile faces (in parallel; no tile is voxelised): the same components as
/// openvdb::tools::extractActiveVoxelSegmentMasks, without its O(components x leaves) grouping
/// and per-voxel copy of the tiles.
struct MaskComponents {
    openvdb::BoolTree::Ptr touching;               ///< all components touching a face of box (values false)
    std::vector<openvdb::BoolTree::Ptr> enclosed;  ///< each other component, its own mask (values false, voxels only: no tiles)
};
MaskComponents faceConnectedComponents(const openvdb::BoolTree& mask, const openvdb::CoordBBox& box);

} // namespace flyover
