/// @file contacts.h
/// @brief Contacts between touching loops of colon: where two loops pressed together are
///        joined in the lumen mask through a thin neck, found and cut so that the lumen's
///        topology follows the colon (one unbranched tube per piece) before the centerline and
///        the surface are made.
///
/// Criterion (and why). A colon is one tube: its lumen has no cycles. A contact between two
/// loops adds one; a collapsed or narrowed stretch that continues the tube does not. So a
/// narrow place is cut only when it closes a cycle, and only the narrowest link of that cycle:
/// 1. Cores: voxels at least half as deep as the deepest voxel nearby (D = -sdf, D >= 0.5 x the
///    largest D within about one leaf) and at least one voxel deep. A neck whose inscribed
///    radius is under half the lumen's on both sides breaks the core there.
/// 2. Chunks: the cores are cut into pieces of about chunkMm along their length (shells of
///    breadth-first distance within each core piece, split into connected parts), so that a
///    loop touching itself is two chunks at the contact, not one.
/// 3. Regions: every lumen voxel joins the chunk it is reached from by flooding in order of
///    decreasing D (a watershed of D), so two regions meet at the saddle of D between them,
///    the narrowest place of the passage. Region graph: nodes = regions (radius = their
///    largest D), edges = touching regions (width = D at the saddle).
/// 4. Topology: a maximum spanning tree of the graph by relative width (saddle D / the
///    smaller radius of the two sides) keeps the widest way through the lumen; each edge left
///    out closes a cycle and is its narrowest link.
/// 5. Contact: such an edge is cut when it is narrow (relative width < maxNeckRatio) and the
///    way round without it and without any other narrow link is longer than the straight way
///    (the detour through the region graph >= minDetourRatio x and >= minDetourMm more than
///    the straight distance between the two sides): a loop, not regions meeting three at a
///    time around a bend (small cycles whose way round is about as long as the straight one,
///    which are left alone). On a real colon a tight flexure whose limbs touch skips only
///    ~40 mm of colon, so the detour asked for is modest; a narrow link closing a small cycle
///    is harmless to cut anyway (the path keeps to the wide way round). A narrow link that
///    closes no cycle (a collapse, a stricture, a haustral fold) is never cut: the lumen stays
///    connected there, and pieces that are already apart stay bridged as before. A cycle whose
///    narrowest link is wide (loops fused over a large area) is counted, not cut.
/// Cutting removes the voxels on both sides of the two regions' interface (a wall about two
/// voxels thick: no 26-neighbour of one region is left in the other) from the mask and sets
/// the sdf there to +half a voxel; the lumen voxels nearby get sdf = max(sdf, -(distance to
/// the removed voxels - half a voxel)), so D stays a distance to the (new) wall. A cut that
/// would split the lumen into more pieces is undone.
///
/// What it does not do: it does not look at HU (no wall is detected between the loops; the
/// cut is where the lumen is narrowest); when a real stricture on a loop is narrower (relative
/// to its radius) than the contact that closes the loop, the stricture is what gets cut.
#pragma once

#include "volume/progress.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace flyover {

struct ContactParams {
    bool enabled = true;          ///< false: find nothing, cut nothing
    double maxNeckRatio = 0.5;    ///< a contact's saddle D / the smaller side radius is below this
    double minDetourRatio = 1.5;  ///< the way round / the straight distance, at least
    double minDetourMm = 20.0;    ///< the way round minus the straight distance, at least (mm)
    double chunkMm = 10.0;        ///< length of the core chunks (mm, > 0)
    static constexpr int VERSION = 1;
};

/// A contact: the narrow, cycle-closing link of the lumen that was cut (or kept, see reason).
struct ContactInfo {
    Vec3d positionMm;             ///< the saddle (LPS mm): the narrowest place of the link
    double widthMm = 0;           ///< 2 x D at the saddle: the neck's diameter (mm)
    Vec3d sideMm[2];              ///< the deepest point of the lumen on either side (LPS mm)
    double sideRadiusMm[2] = {0, 0};  ///< D there (mm)
    double straightMm = 0;        ///< distance between the two side points (mm)
    double detourMm = 0;          ///< the way round through the lumen without this link (mm)
    std::size_t voxelsRemoved = 0;
    bool cut = false;             ///< false: reported only (see reason)
    std::string reason;
};

struct ContactReport {
    std::vector<ContactInfo> contacts;  ///< cut ones first, each group narrowest first
    std::size_t regions = 0;            ///< nodes of the region graph
    std::size_t links = 0;              ///< edges of the region graph
    std::size_t cycleLinks = 0;         ///< edges left out of its maximum spanning tree
    /// Cycles with a long way round whose narrowest link is too wide to cut (loops fused over a
    /// large area, or a wide fold bridging the lumen): counted, not cut.
    std::size_t wideCycles = 0;
    std::size_t pieces = 0;             ///< 26-connected lumen pieces (unchanged by the cuts)
};

/// Finds contacts in the lumen of `sdf` (negative inside, world mm, cubic voxels, every lumen
/// voxel active) and cuts them in place in `sdf` and, when given, in `mask` (lumen voxels
/// active, same index space).
/// @throw ParameterError for bad parameters; InputError for an unusable grid; Cancelled
ContactReport cutContacts(openvdb::FloatGrid& sdf, openvdb::BoolGrid* mask,
                          const ContactParams& params, Progress* progress = nullptr);

} // namespace flyover
