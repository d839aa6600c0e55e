/// @file segment.h
/// @brief Colon lumen segmentation on the sparse HU grid, or from an external mask
///        (colon/lumen_mask.h), into a lumen mask and a signed distance level set.
///
/// From HU (segmentLumen):
/// 1. Air candidates (HU < airThresholdHu) among the active (in-body) voxels are split into
///    face-connected components. Components touching the outside of the body or the scan
///    border, lungs (mean HU above lungMinMeanHu), small gas pockets (< minComponentMl) and
///    components much smaller than the colon (< keepFraction of the reference component:
///    the largest remaining one, or the one at seedMm) are dropped; every other component
///    is kept: a collapsed colon gives several pieces, and all of them are kept.
/// 2. Tagged fluid (cleanse = true, colon/cleanse.h): components of voxels above
///    fluidThresholdHu that lie under kept air across a flat air-fluid level join the
///    lumen, together with the partial-volume rim between air and fluid.
/// 3. The lumen surface is placed at the partial-volume midpoint of the HU field: at
///    surfaceIsoHu against air, at the midpoint of wallHu and the pool's fluid HU against
///    fluid; it is redistanced into a signed distance grid (mm, negative inside).
/// 4. The lumen's connected pieces are measured and ordered along the colon frame.
///
/// A rectal tube (colon/rectal_tube.h) joins the colon's air to the air outside the body: a
/// component touching the outside of at least minComponentMl is searched for one; when the
/// tube is found and cutting it leaves air that no longer touches the outside, the tube's air
/// becomes a component of its own ("rectal tube", dropped) and the rest is classified as usual.
///
/// What it does not do: it does not bridge collapsed segments (the centerline does), and it
/// does not know the patient's orientation beyond what the air-fluid levels tell.
#pragma once

#include "colon/centerline.h"
#include "colon/contacts.h"
#include "volume/progress.h"
#include "colon/rectal_tube.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <optional>
#include <string>
#include <vector>

namespace flyover {

struct SegmentParams {
    double airThresholdHu = -800.0;   ///< air candidates are below this (HU)
    /// Lumen surface against air: the partial-volume midpoint of air (-1000) and the wall
    /// (wallHu, +40 by default), in HU.
    double surfaceIsoHu = -480.0;
    double minComponentMl = 20.0;     ///< air components smaller than this are dropped (mL, >= 0)
    double lungMinMeanHu = -930.0;    ///< a component whose mean HU is above this is lung (HU)
    /// Keep components of at least this fraction of the reference component (the largest
    /// remaining one, or the seeded one), in [0, 1]. Low on purpose: a 60 mL piece of a
    /// collapsed 1.6 L colon must be kept; minComponentMl drops small-bowel gas.
    double keepFraction = 0.02;
    int bandVoxels = 3;               ///< exterior narrow band of the level set (voxels, 1..64)
    /// The colon component is the one containing this point (LPS mm), or the nearest one
    /// within SEED_REACH_MM; it is kept whatever its size and mean HU. Unset: the largest.
    std::optional<Vec3d> seedMm;
    bool cleanse = true;              ///< join tagged fluid under air-fluid levels to the lumen
    double fluidThresholdHu = 200.0;  ///< tagged fluid is above this (HU)
    double wallHu = 40.0;             ///< colon wall (HU): the surface in fluid lies midway to the fluid's HU
    /// External masks (segmentFromMask): the label that is lumen; 0 = every non-zero voxel.
    int maskLabel = 0;
    /// External masks: width (Gaussian sigma, in the mask's largest voxel spacing) of the
    /// constrained smoothing that removes the staircase of a binary mask; 0 = none. The
    /// surface never crosses a mask voxel centre, and the volume is restored afterwards.
    double maskSmoothingVoxels = 1.0;
    /// Contacts between touching loops, cut at the end of the segment stage (contacts.h).
    ContactParams contacts;
    static constexpr int VERSION = 6;  ///< 3: rectal tube found at coarse voxels, filled inside the rectum; 4: its closed tip too; 5: a resampled mask keeps its one-voxel parts and walls; 6: the tube followed on its air core's centre, and through gaps in its ring inside the rectum
};

/// How far from the seed (mm) an air component may lie and still be taken as the seeded one.
inline constexpr double SEED_REACH_MM = 10.0;

/// What happened to one connected air component.
struct AirComponent {
    double volumeMl = 0;
    double meanHu = 0;
    Vec3d centroidMm, minMm, maxMm;  ///< world LPS mm
    bool kept = false;
    /// "colon", "seed" (kept: the seeded component), "lung", "small", "border", "fraction",
    /// "rectal tube" (the tube's air, cut from the colon it joined to the outside)
    std::string reason;
};

/// A component of tagged fluid (above fluidThresholdHu) that touches the kept air.
struct FluidPool {
    double volumeMl = 0;
    double meanHu = 0;              ///< of its interior voxels (the fluid's value)
    double surfaceHu = 0;           ///< where its surface against the wall is placed (HU)
    double levelMm = 0;             ///< position of the air-fluid level along the gravity direction (world mm)
    Vec3d minMm, maxMm;             ///< world LPS mm
    bool joined = false;
    std::string reason;             ///< "air-fluid level" (joined), "no level below air", "cleanse off"
};

/// One connected piece of the final lumen (a collapsed colon has several).
struct LumenPiece {
    int order = 0;                  ///< 0-based rank along the colon frame (see frameAngleDeg)
    double volumeMl = 0;            ///< voxel count x voxel volume
    Vec3d centroidMm, minMm, maxMm; ///< world LPS mm
    /// Median, over the piece's voxels, of the angle around the lumen's centroid in the
    /// coronal (x-z) plane, in [0, 360): 0 points inferior and 30 degrees to the patient's
    /// right, angles grow through the patient's left, superior and right. For a colon this
    /// runs rectum -> sigmoid -> descending -> transverse -> ascending -> cecum.
    double frameAngleDeg = 0;
};

struct LumenSegmentation {
    openvdb::BoolGrid::Ptr mask;   ///< lumen voxels (active = inside); name "lumen_mask"
    openvdb::FloatGrid::Ptr sdf;   ///< signed distance (mm), negative inside; name "lumen_sdf"
    std::vector<AirComponent> components;   ///< largest first
    std::vector<FluidPool> fluidPools;      ///< largest first
    std::vector<LumenPiece> pieces;         ///< in frame order
    /// Unit world direction in which the fluid settles (LPS; +y: the patient lay supine);
    /// the zero vector when no air-fluid level was found.
    Vec3d gravityDirection;
    double lumenVolumeMl = 0;      ///< enclosed by the level set (sub-voxel)
    double maskVolumeMl = 0;       ///< mask voxel count x voxel volume
    double fluidVolumeMl = 0;      ///< joined fluid and air-fluid rim voxels x voxel volume
    /// The rectal tube cut out of the lumen (colon/rectal_tube.h). When found, its tip is also
    /// stored in the level set's metadata (RECTAL_TUBE_TIP_META) for the centerline stage.
    RectalTube rectalTube;
};

/// Name of the lumen_sdf grid's Vec3d metadata holding the rectal tube's tip (LPS mm), present
/// only when a tube was found.
inline constexpr const char* RECTAL_TUBE_TIP_META = "rectal_tube_tip_mm";

/// @throw InputError when no component qualifies as colon lumen (the one-line message lists
///        what was found and why each was rejected), when the seed is in no air component,
///        or when the grid's voxels are not cubic; ParameterError for bad parameters.
LumenSegmentation segmentLumen(const openvdb::FloatGrid& hu, const SegmentParams& params,
                               Progress* progress = nullptr);

/// The run log's line on a lumen in several pieces: their count, then each piece the
/// centerline takes (the largest, and those pieceLargeEnough with `centerline`) in frame order
/// with its volume and centroid, then how many smaller ones there are and their volume in all
/// (a mask's stray voxels can be dozens of crumbs). Every piece stays in the lumen and its mesh
/// whatever its size.
std::string describeLumenPieces(const std::vector<LumenPiece>& pieces, const CenterlineParams& centerline);

/// Checks every SegmentParams field. @throw ParameterError naming the field.
void validateSegmentParams(const SegmentParams& params);

} // namespace flyover
