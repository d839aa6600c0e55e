/// @file review.h
/// @brief Review views for what the fly-over missed. After the fly-over,
///        each missed region of at least minRegionMm2 gets candidate views: the fly-over pair at
///        the region's nearest centerline point rolled so that the region lies in the middle of
///        one view, the pair turned about the centerline in steps from there, the centred pair
///        moved along the path by +-k mm, each raised or lowered (framed half-width scaled), and
///        targeted single views from inside the lumen, looking at the
///        region's centroid along its mean normal or from its nearest centerline point. Every
///        candidate is marked with the coverage rule of computeCoverage (OST, the same rays per
///        view, the footprint), and views are picked greedily, the one that adds the most
///        missed area first, until the fly-over plus review reaches the target fraction or no
///        candidate adds area; then the missed regions are found again and a new round of
///        candidates is made for them (a partly seen region has moved). Regions still missed
///        are reported with a reason. No file I/O.
#pragma once

#include "render/camera.h"
#include "render/coverage.h"
#include "render/ray_scene.h"
#include "volume/centerline_types.h"
#include "volume/progress.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

struct ReviewParams {
    double targetFraction = 0.995;  ///< stop when fly-over plus review sees this much (0..1]
    double minRegionMm2 = 10.0;     ///< plan views for missed regions at least this large (mm^2)
    int maxViews = 400;             ///< at most this many review views
    int maxRounds = 4;              ///< rounds of candidates (regions found again each round)
    std::size_t maxRegionsPerRound = 150;  ///< the largest regions get candidates first
    /// Moves of the rolled pair along the centerline (mm; 0 = at the region's nearest point).
    std::vector<double> shiftsMm{0.0, -5.0, 5.0, -10.0, 10.0, -20.0, 20.0};
    /// Framed half-width of the rolled pair times these factors (1 = the fly-over's elevation).
    std::vector<double> elevationFactors{1.0, 0.6, 1.6};
    /// At the region's own point the pair is also turned about the centerline in steps of this
    /// many degrees from the centred roll (a full turn; 0 = only the centred roll): under an
    /// overhang the view that shows the region is rarely the one centred on it.
    double rollStepDeg = 45.0;
    bool targetedViews = true;      ///< also the single views aimed at the region
    double minGainMm2 = 0.5;        ///< a view must add at least this much area (mm^2)
};

/// One review view: the fly-over pair (two cameras) or a targeted single camera.
struct ReviewView {
    std::string kind;        ///< "rolled_pair", "moved_pair", "elevation_pair", "targeted_normal", "targeted_centerline"
    std::vector<Camera> cameras;       ///< 2 for a pair (camera 0, camera 1), 1 for a targeted view
    std::size_t centerlineIndex = 0;   ///< where the pair stands (targeted: the region's nearest point)
    double arcMm = 0;
    double rollDeg = 0;                ///< the pair's roll (targeted: 0)
    double frameRadiusMm = 0;          ///< the pair's framed half-width (targeted: 0)
    double addedAreaMm2 = 0;           ///< missed area it added when it was picked
    int round = 0;
    /// The region it was planned for, as found in its round.
    Vec3d regionCentroidMm;
    double regionAreaMm2 = 0;
    /// Index into the fly-over's missed regions (CoverageResult::flyover.missed) of the region
    /// it adds the most area to; -1 when it adds only to smaller, unlisted ones.
    long flyoverRegion = -1;
};

/// A region missed by fly-over and review together, with why no view shows it.
struct UnreachedRegion {
    MissedRegion region;
    std::string reason;
    double bestCandidateAreaMm2 = 0;  ///< the most of it any candidate of the last round showed
};

struct ReviewResult {
    std::vector<ReviewView> views;
    /// Fly-over plus review: seen flags, fraction, regions >= the coverage's minRegionMm2.
    MethodCoverage withReview;
    /// One per region of withReview.missed, same order.
    std::vector<UnreachedRegion> unreached;
    bool targetReached = false;
    std::size_t candidatesEvaluated = 0;
    uint64_t rays = 0;
    int rounds = 0;
};

/// Plans review views after `flyover` = computeCoverage(scene, centerline, coverage). The
/// candidates use coverage.flyover (fov, clip offset, direction), coverage.viewPx, ost and
/// footprint, and the framed half-widths `frameRadiiMm` (one per centerline point, as the
/// fly-over used).
/// @throw ParameterError for parameters out of range or sizes that do not match
ReviewResult planReview(const RayScene& scene, const Centerline& centerline, const CoverageParams& coverage,
                        const std::vector<double>& frameRadiiMm, const CoverageResult& flyover,
                        const ReviewParams& params = {}, Progress* progress = nullptr);

/// The roll (degrees, in (-180, 180]) at which camera 0 of the fly-over pair at `point` looks
/// straight at a wall point in `directionMm` from the centerline (camera 1 then looks away).
/// @throw InputError when the direction is parallel to the centerline tangent.
double centredRollDeg(const CenterlinePoint& point, const Vec3d& directionMm);

} // namespace flyover
