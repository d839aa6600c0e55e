/// @file lumen_accounting.h
/// @brief What of the lumen the centerline does not pass through. A flood through the lumen
///        from the path's voxels gives every lumen voxel the path point that reaches it first
///        (its owner) and how far it lies from it along the lumen. A voxel farther than twice
///        its owner's radius (plus two voxels) is not on the path's way; such voxels, grouped
///        into 26-connected regions, are listed when they hold at least minMl: a short dead end
///        (a diverticulum, a haustral pouch, the appendix), a loop or stretch the path never
///        enters (cut off by a contact decision, skipped by the chain), or a separate piece of
///        lumen the path does not join.
#pragma once

#include "colon/lumen_index.h"
#include "volume/centerline_types.h"
#include "volume/vec3.h"

#include <openvdb/math/Transform.h>

#include <string>
#include <vector>

namespace flyover {

/// Dead ends shorter than this beyond the path's reach are a pouch of the wall (mm).
inline constexpr double DEAD_END_MAX_MM = 30.0;

struct LeftOutLumen {
    double volumeMl = 0;
    Vec3d centroidMm;             ///< LPS mm
    /// Arc length (mm from the rectum end) of the path point whose reach it lies beyond; -1 for a
    /// separate piece (not reached from the path at all).
    double arcMm = -1;
    double extentMm = 0;          ///< how far it reaches beyond that point's reach, along the lumen
    /// "dead end", "not entered", "separate piece" or "far branch" (the far tube the path
    /// leaves out, Centerline::leftOutBranchMm, reported on its own as well)
    std::string kind;
    std::string reason;           ///< a sentence for the report and the run log
};

/// @param index  the lumen voxels of the grid whose transform is `xf`
/// @param cl     the path (its bridged points are not in the lumen and seed nothing)
/// @param minMl  regions smaller than this are not listed
/// @return the regions, largest first
std::vector<LeftOutLumen> leftOutLumen(const lumen_index::LumenIndex& index, const openvdb::math::Transform& xf,
                                       const Centerline& cl, double minMl);

} // namespace flyover
