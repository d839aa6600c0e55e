/// @file centerline.h
/// @brief The lumen centerline from the signed distance grid: one ordered, smooth path from
///        the rectum to the cecum through the middle of the lumen, resampled at a uniform
///        arc-length step, with the gaps between the pieces of a collapsed colon bridged.
///
/// Per lumen piece (26-connected component of the voxels where sdf < 0):
/// 1. endpoints by geodesic farthest points (two breadth-first passes over the piece);
/// 2. a minimal path between them whose cost per unit length is D^-wallPenalty (D: distance to
///    the wall), so it keeps to the middle of the lumen;
/// 3. the path is moved to the centroids of the lumen's cross-sections perpendicular to it
///    (sections cut by a haustral fold or a large polyp are recognised by their area and
///    skipped), smoothed along its arc length, and continued straight into the blind ends;
///    where the centred path is less than half as deep as the ridge of D beside it and has moved
///    off it by more than half that depth (sections that overlap in a bend tighter than the lumen
///    radius pull it onto the inner wall), the ridge is kept.
/// The rectum is the lowest piece end in world z, or the piece end nearest to rectumMm. Each
/// piece's path runs between its own farthest pair whatever the hint, so the path traced from
/// either end is the same curve. When the hint lies at no piece end (its nearest lumen voxel
/// farther than two depths from it), or without a hint the lowest end lies more than 40 mm above the lowest lumen voxel,
/// that point's piece is traced again from the end of the tube nearest to it (the voxel farthest
/// from its farthest voxel) to the farthest voxel from there along the lumen (the cecum). Pieces are joined
/// into one chain starting at the rectum, in the order and directions that minimise the total
/// bridge length plus a turning penalty; each gap is bridged by a smooth curve whose points
/// are flagged `bridged`.
///
/// What it does not do: it does not read files, segment, or look at HU; a bridge does not
/// follow the collapsed bowel through the tissue (there is no lumen there to follow).
#pragma once

#include "colon/lumen_accounting.h"
#include "volume/centerline_types.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <optional>
#include <string>
#include <vector>

namespace flyover {

struct CenterlineParams {
    double stepMm = 1.0;            ///< arc-length step of the output (mm, > 0)
    double wallPenalty = 2.0;       ///< exponent p of the cost 1/D^p (D: distance to wall, mm; >= 0)
    double smoothingMm = 4.0;       ///< Gaussian smoothing sigma along the path (mm, >= 0)
    std::optional<Vec3d> rectumMm;  ///< the path starts at the lumen end nearest this point (LPS mm;
                                    ///< e.g. the anus, or the rectal tube's entry)
    /// Move the path to the centroids of the lumen cross-sections (robust to haustral folds and
    /// polyps); false: keep it on the ridge of D (the medial axis).
    bool centerSections = true;
    /// Lumen pieces smaller than this are ignored (mL, >= 0); the largest piece is always used.
    double minPieceMl = 0.5;
    /// ... and so are pieces smaller than this fraction of the largest ([0, 1]): crumbs, gas in
    /// small bowel, a mask's stray parts. A stretch of colon between two collapses holds a few
    /// per cent of the lumen or more (the CT segmentation keeps air components of 2% and up).
    double minPieceFraction = 0.01;
    /// Bridge cost added per radian that a bridge turns away from the piece ends' directions,
    /// when choosing the order of the pieces (mm per radian, >= 0).
    double bridgeTurnMmPerRad = 20.0;
    /// Path points closer than this to the wall outside bridges are reported (mm, >= 0).
    double nearWallMm = 1.0;
    /// Where a narrowing splits a piece's core, the route is searched on the core plus the
    /// piece's voxels within this many millimetres (in steps, at least three) of the narrowings
    /// and the piece's ends instead of on the whole piece (mm; 0: the whole piece). Not a stage parameter: the
    /// tests and benches compare the two.
    double corridorMm = 5.0;
    static constexpr int VERSION = 8;  // 8: anatomical segments and landmarks in centerline.json
};

/// One lumen piece as the centerline saw it.
struct CenterlinePieceInfo {
    double volumeMl = 0;            ///< voxel count x voxel volume
    bool used = false;              ///< false: smaller than minPieceMl or minPieceFraction
    int chainIndex = -1;            ///< position in the travel order (0: rectum piece), -1 if unused
    double pathLengthMm = 0;        ///< length of its own path (before resampling)
    Vec3d entryMm, exitMm;          ///< where the path enters and leaves it (LPS mm)
    /// Where its minimal path was searched, the first of these that joins its ends: "coarse
    /// core" (the deep voxels' lattice of even coordinates), "core" (the deep voxels), "core
    /// and corridors" (the core split, e.g. by a narrowing: the core with the voxels round the
    /// narrowing and the ends, CenterlineParams::corridorMm), "whole piece"; empty if unused.
    std::string routeSearchedOn;
};

/// One bridge across a gap between pieces.
struct CenterlineBridgeInfo {
    int fromPiece = 0, toPiece = 0; ///< indices into CenterlineReport::pieces
    double gapMm = 0;               ///< straight distance between the two piece ends
    double lengthMm = 0;            ///< length of the bridge curve
};

/// A stretch of the path closer to the wall than CenterlineParams::nearWallMm (not bridged):
/// the path squeezes through a narrow place of the lumen there (a contact left uncut, a
/// stricture, a collapse that kept a thread of lumen).
struct CenterlineNearWall {
    double fromArcMm = 0, toArcMm = 0;  ///< arc lengths from the rectum end (mm)
    double minRadiusMm = 0;             ///< smallest D along it
    Vec3d positionMm;                   ///< where D is smallest (LPS mm)
};

/// A narrow tube at the lumen's far end that the path leaves out (centerline_far_end.h): the
/// terminal ileum, gas-filled through an open ileocecal valve, off the cecum.
struct CenterlineFarBranch {
    Vec3d mouthMm;                ///< where the tube leaves the wide lumen (on the old path)
    Vec3d endMm;                  ///< where the old path ended, in the tube
    double lengthMm = 0;          ///< the old path from the mouth to that end
    double depthMm = 0;           ///< the tube's depth (radius)
    double wideDepthMm = 0;       ///< the wide lumen's
    double wideEndBeyondMouthMm = 0;  ///< how far (26-neighbour steps x voxel) the wide lumen's own end lies beyond the mouth
};

/// Without a rectum hint, the rectum is the lowest piece end; when that lies more than this above
/// the lowest lumen voxel (mm), the farthest pair missed the rectum (the path end stops about a
/// lumen radius short of the cap wall; a distended rectum is up to ~25 mm in radius) and the
/// piece is traced again from the tube's end nearest to that voxel. A path that still starts
/// higher is flagged for review.
inline constexpr double LOWEST_END_SLACK_MM = 40.0;

/// The far end is traced to the wide lumen's own end when it lies at least this many wide
/// depths beyond the mouth of a narrow tube (the cecum's end 5-8 cm below the valve, its depth
/// 2.5-4.5 cm; a narrow cecum off a wide ascending colon has no wide end beyond its mouth).
inline constexpr double FAR_SAC_DEPTHS = 1.5;

/// A narrow tube at the far end with no wide end beyond its mouth is left out when it is at most
/// this fraction as deep as the wide lumen (the appendix, 1-4 mm in radius, off a cecum of
/// 20-45 mm; a poorly distended cecum, a third or more as deep as the colon before it, stays).
inline constexpr double APPENDIX_DEPTH_FRACTION = 0.25;

struct CenterlineReport {
    std::vector<CenterlinePieceInfo> pieces;   ///< largest first
    std::vector<CenterlineBridgeInfo> bridges; ///< in travel order
    /// "lowest end", "end nearest to the lowest lumen voxel", "piece end nearest to rectum_mm"
    /// or "end of the tube nearest to rectum_mm" (the hint lay at no piece end: re-traced)
    std::string rectumRule;
    Vec3d lowestLumenMm;                       ///< the lowest lumen voxel in world z (LPS mm)
    std::vector<CenterlineNearWall> nearWall;  ///< in path order
    std::optional<CenterlineFarBranch> farBranchLeftOut;
    /// How the output path turns (kinks make the fly-over cameras spin): the largest angle
    /// between consecutive steps and between consecutive camera normals (degrees), and how many
    /// steps turn more than 30 degrees and how many normals step more than 15.
    double maxTurnDeg = 0, maxNormalStepDeg = 0;
    int turnsOver30 = 0, normalStepsOver15 = 0;
    /// Lumen the path does not pass through (lumen_accounting.h), regions of LEFT_OUT_MIN_ML and up.
    std::vector<LeftOutLumen> leftOut;
};

/// The smallest region of lumen off the path that the report lists (mL).
inline constexpr double LEFT_OUT_MIN_ML = 3.0;

/// @param sdf      lumen signed distance grid in world mm, negative inside the lumen, with
///                 cubic voxels and a linear transform; every lumen voxel active (as
///                 segmentLumen and segmentFromMask produce it)
/// @param params   see CenterlineParams
/// @param report   optional: the pieces and bridges
/// @return points ordered rectum -> cecum, stepMm apart; radiusMm = D at the point, and on
///         bridges the linear interpolation of D between the two piece ends (there is no lumen
///         to measure there)
/// @throw InputError when the lumen is empty or the grid unusable; ParameterError for bad
///        parameters; Cancelled through `progress`
Centerline extractCenterline(const openvdb::FloatGrid& sdf, const CenterlineParams& params,
                             Progress* progress = nullptr, CenterlineReport* report = nullptr);

/// Whether extractCenterline takes a lumen piece that is not the largest: `size` and
/// `largestSize` in any one unit, `sizeToMl` converting it to mL (voxels: the voxel's volume;
/// mL: 1). At least params.minPieceMl and params.minPieceFraction of the largest.
inline bool pieceLargeEnough(double size, double largestSize, double sizeToMl, const CenterlineParams& params)
{
    return size * sizeToMl >= params.minPieceMl && size >= params.minPieceFraction * largestSize;
}

namespace detail {
/// The centerline's kink removal on its own (for tests): `fine` resampled every fineMm, then
/// smoothed again where it turns more than 12 degrees per 1 mm chord, never closer to the wall of
/// `sdf` than min(1 mm, where it was).
std::vector<Vec3d> removePathKinks(const std::vector<Vec3d>& fine, const openvdb::FloatGrid& sdf, double fineMm);
} // namespace detail

} // namespace flyover
