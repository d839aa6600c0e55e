/// @file segment_tools.h
/// @brief Internal to volume/: thin wrappers over the OpenVDB tool families that lumen
///        segmentation uses (morphology, connected components, fast sweeping, narrow-band
///        trimming), so that those heavy headers are compiled in one translation unit
///        (segment_tools.cpp; style.md §4) while segment.cpp, cleanse.cpp and lumen_mask.cpp
///        stay light. All of them work on the pre-instantiated BoolTree and FloatGrid types.
#pragma once

#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <vector>

namespace flyover {
struct LumenSegmentation;
struct SegmentParams;
} // namespace flyover

namespace flyover::detail {

/// Which neighbours one dilation step reaches: the 6 face neighbours (grows a diamond) or
/// all 26 (grows a cube, which contains the Euclidean ball of the same radius).
enum class Neighbours { Face, All };

/// Grows the active voxels by `iterations` steps, in place (active tiles are left alone).
void dilateVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours);

/// Shrinks the active voxels by `iterations` steps, in place: a voxel stays active only when
/// every voxel within `iterations` steps (face or all neighbours) is active.
void erodeVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours);

/// The voxels of `seed` plus those of `allowed` reachable from it by face steps, grown one
/// voxel per iteration (meant for thin shells: the cost is iterations x shell size).
openvdb::BoolTree::Ptr reachableWithin(const openvdb::BoolTree& seed,
                                       const openvdb::BoolTree& allowed, int maxIterations);

/// Signed distance (world units, the grid's transform) to the zero crossing of `f`, on the
/// active voxels of `f`, negative where f < 0: first-order fast sweeping, one round of the
/// eight sweep orderings. The interface is placed along each axis by linear interpolation of
/// f between neighbouring voxels. The result is bit for bit that of
/// openvdb::tools::sdfToSdf(f, 0, 1), computed leaf by leaf as a dependency graph
/// (redistance.cpp): several times faster, a fraction of the memory, the same on any number
/// of threads. @throw openvdb::RuntimeError when `f` has active tiles.
/// @note Values of exactly 0 in `f` are first set to the smallest positive float (outside):
///       the sweeping's sign is ambiguous there (integer HU equal to the iso-value, a
///       resampled mask at exactly one half), and such a voxel can come out deep inside.
/// @param skippedLeafSweeps when given, receives how many (leaf, sweep) pairs were skipped
///        because the sweep could not change the leaf (tests; see redistance.cpp)
openvdb::FloatGrid::Ptr redistance(openvdb::FloatGrid& f, std::size_t* skippedLeafSweeps = nullptr);

/// Deactivates exterior voxels farther than `bandMm` from the surface, sets the background
/// to +bandMm (inside tiles: -bandMm) and prunes: a level set with a full interior and an
/// exterior narrow band.
void trimExteriorBand(openvdb::FloatTree& sdf, float bandMm);

/// Removes inactive leaves and tiles.
void pruneInactive(openvdb::BoolTree& tree);
void pruneInactive(openvdb::FloatTree& tree);

// ---- shared by segmentLumen() and segmentFromMask(); defined in segment.cpp

/// Finishes a segmentation from a signed distance grid (mm, negative inside, full interior,
/// exterior band of at least bandVoxels + 1): trims the band, names the grids, builds the
/// mask, measures the volumes and the pieces (sets every LumenSegmentation field except
/// components, fluidPools, gravityDirection and fluidVolumeMl).
void finishLumen(openvdb::FloatGrid::Ptr sdf, const SegmentParams& params,
                 LumenSegmentation& result, Progress* progress);

} // namespace flyover::detail
