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
///    and leaves the body: from a CT, it touches the air outside the body or the scan's edge,
///    or its outer end lies within TUBE_MAX_WALL_MM + a voxel of it (a closed outer end);
///    from a mask, it hangs downwards from within 60 mm of the lowest point of the wide part
///    (the rectum) and touches the image's edge or ends as the lowest point of the mask.
/// 3. From a CT, the tube is followed into the rectum past the opening's reach for as long
///    as its cross-section shows the tube: air inside, a ring (its wall: not air) around; the
///    tip is where that ends. It is followed in straight runs (at most 4), each along the
///    direction within 90 degrees of the previous one that goes farthest (a catheter bends
///    where it enters the rectum), each from the centre of the tube's air core; the followed
///    axis is centred on the core. Inside the rectum's air (the lumen all round beyond the
///    wall) a ring with one side missing still counts (coarse voxels drop a side of a thin
///    wall). From a mask the same with the ring outside the set: where
///    the mask shows the tube's wall inside the rectum's air, else the tip is where the thin
///    piece meets the wide part.
/// 4. The tube's voxels (the piece, and the air within its lumen radius + one voxel of the
///    axis up to the tip) are taken out of the lumen.
/// 5. Where the colon's lumen (air, and from a CT the tagged fluid) surrounds the tube (inside
///    the rectum), the tube's lumen and wall
///    (its lumen radius + TUBE_MAX_WALL_MM + a voxel) are given to the lumen: the surface shows the
///    rectum without the catheter, and its medial axis (the path) runs down the rectum's
///    middle instead of beside the tube.
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
/// A tube's plastic wall is at most this thick (mm): from a CT, the air outside the body is
/// looked for this far (plus a voxel) beyond the tube's air, since the wall lies between them
/// (an outer end closed by a cap or a connector, or a tube lying in the outside air).
inline constexpr double TUBE_MAX_WALL_MM = 3.0;

/// What was found of a rectal tube (world LPS mm).
struct RectalTube {
    bool found = false;
    Vec3d tipMm;             ///< the tube's inner end, in the rectum (the rectum hint for the centerline)
    Vec3d entryMm;           ///< where it crosses the body surface (CT); its outer end (mask)
    Vec3d outerEndMm;        ///< the outermost tube voxel seen (at the scan's or image's edge, or outside the body)
    double lengthMm = 0;     ///< along its axis, outer end to tip
    double diameterMm = 0;   ///< of its air lumen (equivalent diameter of the middle part)
    double volumeMl = 0;     ///< air (or mask) voxels taken out of the lumen
    double filledMl = 0;     ///< tube (lumen and wall) within the colon's air, given to the lumen
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
    /// A piece also leaves the body when `outside` holds for an index within this many voxels
    /// (a cube) of its outer end (CT: tubeWallReachVoxels; the wall lies between the tube's air
    /// and the outside). 0: only a face neighbour of a piece voxel counts.
    int outsideReachVoxels = 0;
};

/// Voxels (of size `voxelMm`) across a tube's wall and one voxel more: how far beyond the
/// tube's air the outside may begin (TubeSearch::outsideReachVoxels for a CT).
int tubeWallReachVoxels(double voxelMm);

/// True when some active voxel of `set` lies within `reach` voxels (a cube) of an inactive
/// voxel of `hu` (outside the body or the scan): the set may hold a tube that leaves the body
/// through its wall. Cheap where `hu` is fully active around a leaf (inside the body).
bool nearInactive(const openvdb::BoolTree& set, const openvdb::FloatTree& hu, int reach);

/// Looks for a rectal tube in `set` (air of one component, or a whole mask) whose index ->
/// world map is `xf` (cubic voxels). @return the voxels to take out of the set (an empty tree
/// when none was found); `info` is filled when one was. When `fill` is given and a tube was
/// found, *fill receives the voxels to give to the lumen: the tube's lumen and wall where the
/// colon's air surrounds it (step 5 of the file comment).
openvdb::BoolTree::Ptr findRectalTube(const openvdb::BoolTree& set, const openvdb::math::Transform& xf,
                                      const TubeSearch& search, RectalTube& info,
                                      openvdb::BoolTree::Ptr* fill = nullptr);

/// Step 5 of the file comment: the voxels to give to the lumen, the tube's lumen and wall
/// where `lumen` surrounds it (a probe ring beyond its wall, in RING_MIN_HITS of 12
/// directions). `lumen`: the colon's lumen without the tube (`cut`, findRectalTube's result;
/// its voxels never count as lumen); from a CT, its air with the tagged fluid and the
/// air-fluid rim, so that a tube lying against the fluid (supine: the posterior rectum) is
/// filled as one in air is. An empty tree when `info` has no tube.
openvdb::BoolTree::Ptr rectalTubeFill(const openvdb::BoolTree& lumen, const openvdb::BoolTree& cut,
                                      const openvdb::math::Transform& xf, const RectalTube& info);

} // namespace detail
} // namespace flyover
