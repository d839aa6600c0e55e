/// @file rectal_tube.h
/// @brief The rectal tube (insufflation catheter): recognised in the lumen's air or in an
///        external mask, cut out of the lumen and reported.
///
/// A rectal tube is a plastic catheter (wall about +100..+300 HU, air lumen 5-8 mm wide) that
/// runs from outside the body through the anus into the rectum. Its air joins the colon's air
/// to the air outside the body, so that the colon would be dropped as "air connected to the
/// outside", or would keep a thin tube leading out of the body.
///
/// How it is found (findRectalTube):
/// 1. The thin parts of the air (or mask): a morphological opening by a cube that no tube lumen
///    of radius up to TUBE_MAX_RADIUS_MM fits in (erosion, then growth back within the set);
///    what the opening leaves out is split into face-connected pieces.
/// 2. A piece is a tube when it is attached to the wide part, thin (equivalent diameter of its
///    middle part at most TUBE_MAX_DIAMETER_MM), long (at least TUBE_MIN_LENGTH_MM along its
///    axis), straight (its axis strays at most max(5 mm, 20% of its length) from the chord)
///    and leaves the body: from a CT, it touches the air outside the body or the scan's edge;
///    from a mask, it hangs downwards from within 60 mm of the lowest point of the wide part
///    (the rectum) and touches the image's edge or ends as the lowest point of the mask.
/// 3. From a CT, the tube is followed into the rectum past the opening's reach along its
///    axis for as long as its cross-section shows the tube: air inside, a dense ring (the
///    wall) around; the tip is where that ends. From a mask the tip is where the thin piece
///    meets the wide part (the mask cannot show the tube inside the rectum's air).
/// 4. The tube's voxels (the piece, and the air within its lumen radius + one voxel of the
///    axis up to the tip) are taken out of the lumen.
#pragma once

#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <functional>
#include <vector>

namespace flyover {

/// Tubes of air up to this radius (mm) are thin (the opening removes them entirely).
inline constexpr double TUBE_MAX_RADIUS_MM = 4.5;
/// A tube's air lumen is at most this wide (equivalent diameter of its middle part, mm).
inline constexpr double TUBE_MAX_DIAMETER_MM = 10.0;
/// A tube is at least this long along its axis (mm).
inline constexpr double TUBE_MIN_LENGTH_MM = 20.0;

/// What was found of a rectal tube (world LPS mm).
struct RectalTube {
    bool found = false;
    Vec3d tipMm;             ///< the tube's inner end, in the rectum (the rectum hint for the centerline)
    Vec3d entryMm;           ///< where it crosses the body surface (CT); its outer end (mask)
    Vec3d outerEndMm;        ///< the outermost tube voxel seen (at the scan's or image's edge, or outside the body)
    double lengthMm = 0;     ///< along its axis, outer end to tip
    double diameterMm = 0;   ///< of its air lumen (equivalent diameter of the middle part)
    double volumeMl = 0;     ///< air (or mask) voxels taken out of the lumen
    std::vector<Vec3d> axisMm;  ///< outer end -> tip, about 2 mm apart
};

namespace detail {

/// Where to look and what the surroundings say.
struct TubeSearch {
    /// From a CT: the HU tree (same index space as the set); follows the tube into the
    /// rectum by its dense ring and finds the body surface. nullptr for masks.
    const openvdb::FloatTree* hu = nullptr;
    /// True for an index outside the body or the image (the tube leaves through there).
    std::function<bool(const openvdb::Coord&)> outside;
    /// Masks: also accept a piece whose outer end is the lowest point of the set.
    bool acceptLowestEnd = false;
};

/// Looks for a rectal tube in `set` (air of one component, or a whole mask) whose index ->
/// world map is `xf` (cubic voxels). @return the voxels to take out of the set (an empty tree
/// when none was found); `info` is filled when one was.
openvdb::BoolTree::Ptr findRectalTube(const openvdb::BoolTree& set, const openvdb::math::Transform& xf,
                                      const TubeSearch& search, RectalTube& info);

} // namespace detail
} // namespace flyover
