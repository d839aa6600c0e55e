/// @file contacts.h
/// @brief Contacts between touching loops of colon: where two loops pressed together are
///        joined in the lumen mask through a thin neck, found and cut so that the lumen's
///        topology follows the colon (one unbranched tube per piece) before the centerline.
///
/// Criterion (and why). A colon is one tube: no cycles, no branches. A contact joins two loops
/// through a neck where two walls meet; a collapsed or narrowed stretch continues one tube.
/// 1. Cores: voxels at least half as deep as the deepest nearby (D = -sdf) and >= 1 voxel deep;
///    cut into chunks of ~chunkMm along their length; every lumen voxel joins the chunk it is
///    reached from by flooding in order of decreasing D (a watershed of D): regions meet at
///    the saddle of D, the narrowest place between them. Region graph: nodes = regions
///    (radius = their deepest D), links = touching regions (width = D at the saddle).
/// 2. A maximum spanning tree of the graph by relative width (saddle D / the smaller radius of
///    the two sides) keeps the widest way through the lumen. A link is narrow when its relative
///    width is below maxNeckRatio. A narrow link is a contact when either
///    a. it closes a cycle and the way round is long: the shortest path through the lumen
///       deeper than the neck (so it cannot cross this neck, nor a narrower one) between the
///       two sides' deepest points is at least minDetourRatio x the straight distance and the
///       straight distance + max(minDetourMm, pi x the larger side radius). Why: within one
///       tube (around a polyp or a fold that meets the opposite wall, regions around a bend or
///       a wide cecum) the way round is at most about half a circumference longer than the
///       straight way; between two loops it is the colon between them. Measured through the
///       voxels, not the region graph (whose zig-zag between region peaks made small cycles
///       look long: the false cuts of the first version). Widest first; a cut is no way round.
///    b. or it closes no cycle (a collapse between the two loops keeps them apart along the
///       colon: the first version missed every such contact from the CT phantoms) and it meets
///       a tube from the side on both hands: on each side (the spanning tree without the link),
///       the longest path and the point of it nearest the link leave at least
///       max(minArmMm, minArmRadii x radius) of tree on either hand, and the two arms leave
///       that point in opposite directions (a tube passing it, not a hairpin). A collapse,
///       stricture or fold lies across the tube: on one side it is the end of the longest path
///       (arm ~0), or, where the tube's end holds two regions across it, the path turns there
///       (a hairpin).
/// Links cut within the smaller side radius (>= 3 voxels) of each other are one contact.
/// Cutting removes the voxels of both regions along their interface (a wall ~2 voxels thick)
/// from the mask, sets the sdf there to +half a voxel and caps the depth of the lumen nearby
/// by the distance to the removed voxels. A cut that splits the lumen more than its kind
/// allows (a: no new piece; b: one) is undone. Cycles with a long way round whose narrowest
/// link is wide (loops fused over a large area) are counted, not cut.
///
/// What it does not do: it does not look at HU (no wall is detected between the loops; the
/// cut is where the lumen is narrowest); a loop's blind end (or a collapse's end) touching
/// another loop is not cut (b needs a tube on both hands); when a stricture on a loop is
/// narrower, relative to its radius, than the contact closing the loop, the stricture is cut;
/// the region graph's detour estimate only counts wide cycles.
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
    /// A link with no way round is a contact only when it meets a tube from the side on both
    /// sides, with at least this much tube (mm along the region tree) on either hand ...
    double minArmMm = 15.0;
    /// ... and at least this many times that side's lumen radius.
    double minArmRadii = 1.0;
    static constexpr int VERSION = 2;
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
    std::size_t links = 1;        ///< region links cut at this place (a channel may touch several)
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
