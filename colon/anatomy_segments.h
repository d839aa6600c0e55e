/// @file anatomy_segments.h
/// @brief The colon's anatomical segments along the centerline (rectum, sigmoid, descending,
///        splenic flexure, transverse, hepatic flexure, ascending, cecum) and its landmarks
///        (the rectosigmoid and descending-sigmoid junctions, the two flexures, the cecum),
///        found from the path's geometry in the patient's frame; and the seen share of the
///        wall per segment.
///
/// The rules (docs/method.md, "Anatomical segments"), each a step function below:
/// 1. body axes: the patient frame (LPS) when the scan states it and the path agrees with it
///    (the path's high points on the patient's left come before those on the right, as the
///    descending colon comes before the ascending); else from the path alone.
/// 2. flexures: the splenic flexure is the highest point on the left, the hepatic flexure the
///    top of the right limb climbed from the cecum.
/// 3. descending-sigmoid junction: from the splenic flexure back down the left flank, the
///    lowest point before the path rises again or swings medially.
/// 4. rectosigmoid junction: where the path from the anal end stops rising.
/// 5. cecum: the last stretch of the path.
/// 6. flexure segments: a fixed arc either side of each flexure.
#pragma once

#include "volume/centerline_types.h"
#include "volume/vec3.h"

#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace flyover {

/// The segment names, in path order (rectum first).
const std::vector<std::string>& anatomySegmentNames();

/// What the caller knows of the patient frame of the world coordinates.
enum class PatientFrame {
    Stated,  ///< the scan's header gives an orientation: world LPS is the patient's
    Unknown  ///< no orientation known (a bare mask): label from the path alone
};

/// Unit directions, in world coordinates, of the patient's left, posterior and superior.
struct BodyAxes {
    Vec3d left{1, 0, 0}, posterior{0, 1, 0}, superior{0, 0, 1};
};

/// Rule numbers and distances of the labelling (mm of arc unless said).
struct AnatomySegmentParams {
    /// Flexure candidates lie at least this fraction of the path's half-width off the midline.
    double flexureLateralFraction = 0.25;
    /// The walks along a flank (down the left from the splenic flexure, up the right from the
    /// cecum) stop where the path has turned back this far from the lowest (highest) point so
    /// far ...
    double limbTurnStopMm = 20.0;
    /// ... or lies this much medial of it.
    double limbMedialStopMm = 40.0;
    /// Rectosigmoid junction: the first point past `rectumMinMm` where the chord over the next
    /// `rectumChordMm` climbs less than `rectumMinElevationDeg`; at most `rectumMaxMm`, and
    /// `rectumDefaultMm` when the path never levels off before that.
    double rectumMinMm = 40.0;
    double rectumChordMm = 20.0;
    double rectumMinElevationDeg = 30.0;
    double rectumMaxMm = 200.0;
    double rectumDefaultMm = 150.0;
    /// The cecum: the last `cecumMm` of the path, at most a third of the arc past the hepatic flexure.
    double cecumMm = 60.0;
    /// Flexure segments: this much arc either side of each flexure point.
    double flexureHalfMm = 40.0;
};

struct AnatomySegments {
    std::vector<std::string> segment;           ///< one per centerline point
    std::vector<CenterlineLandmark> landmarks;  ///< path order
    std::string frame;                          ///< "patient" or "path only"
    std::string frameReason;                    ///< why "path only" (empty for "patient")
    BodyAxes axes;                              ///< the axes the rules used
};

// ---- The steps (exposed for tests) ---------------------------------------------------------

/// LPS world axes: the patient frame.
BodyAxes bodyAxesFromPatientFrame();

/// Axes from the path alone, among the world axes (a scan is acquired axially, so its axes are
/// the body's up to order and sign): superior is the axis along which the path's first point
/// (the anal end) lies farthest from the middle of the path's extent, pointing from it to the
/// middle; left is
/// the wider of the other two, signed so that the path's high points on the left come first
/// (pathRunsLeftBeforeRight); posterior completes a right-handed frame.
BodyAxes bodyAxesFromPath(const std::vector<Vec3d>& positions);

/// True when the path's high points (the upper third of its height) on the left of its
/// midline come before, on average along the path, those on its right: the descending colon
/// and splenic flexure before the hepatic flexure and ascending colon.
bool pathRunsLeftBeforeRight(const std::vector<Vec3d>& positions, const BodyAxes& axes);

struct Flexures {
    std::size_t splenic = 0, hepatic = 0;
    bool found = false;
};
/// Splenic: the highest point at least flexureLateralFraction of the half-width left of the
/// path's lateral midline. Hepatic: the top of the right limb, climbed back from the lowest
/// point of the path's final stretch (its last tenth, at least 100 mm: the cecum) until the
/// path falls limbTurnStopMm below the highest point so far or lies limbMedialStopMm medial of
/// it; when that top is not as far right as the splenic flexure is left, the highest point that
/// far right after the splenic flexure. (The highest point on the right can be the top of a
/// redundant transverse loop near the midline: the right limb's top is the flexure.)
Flexures findFlexures(const std::vector<Vec3d>& positions, const BodyAxes& axes, const AnatomySegmentParams& params);

/// From the splenic flexure back towards the rectum: the lowest point reached before the path
/// rises limbTurnStopMm above it or lies limbMedialStopMm medial of it.
std::size_t findDescendingSigmoidJunction(const std::vector<Vec3d>& positions, const BodyAxes& axes,
                                          std::size_t splenic, const AnatomySegmentParams& params);

/// The first point past rectumMinMm whose chord to the point rectumChordMm on climbs less than
/// rectumMinElevationDeg, capped at rectumMaxMm and 10 mm before `limit` (the
/// descending-sigmoid junction); rectumDefaultMm (capped alike) when none does.
std::size_t findRectosigmoidJunction(const std::vector<Vec3d>& positions, const BodyAxes& axes, double stepMm,
                                     std::size_t limit, const AnatomySegmentParams& params);

/// The first point of the cecum: cecumMm before the path's end, at most a third of the way
/// from the hepatic flexure to the end.
std::size_t findCecumStart(std::size_t pointCount, double stepMm, std::size_t hepatic,
                           const AnatomySegmentParams& params);

/// The whole labelling. Paths too short or without two flexures (not a whole colon) are
/// labelled as far as the rules go: every point still gets a segment.
AnatomySegments labelAnatomySegments(const Centerline& centerline, PatientFrame frame,
                                     const AnatomySegmentParams& params = {});

/// labelAnatomySegments and stores the result in the centerline (segment, landmarks, frame).
void addAnatomySegments(Centerline& centerline, PatientFrame frame, const AnatomySegmentParams& params = {});

// ---- Seen share per segment -----------------------------------------------------------------

/// A triangle with this nearest index belongs to no segment (e.g. the wall of a left-out
/// far tube): it is not counted.
inline constexpr std::size_t NOT_ON_PATH = std::numeric_limits<std::size_t>::max();

struct SegmentSeenShare {
    std::string segment;
    double areaMm2 = 0;
    double seenAreaMm2 = 0;
    double fraction = 0;  ///< seen / area (0 when the segment has no wall)
};

/// Per segment (in path order, those that occur in segmentPerPoint), the wall area whose
/// triangles' nearest centerline point carries that segment, and the part of it seen
/// (seenPerTriangle non-zero).
/// @throw std::invalid_argument when the triangle arrays differ in length, or an index other
///        than NOT_ON_PATH is not a centerline point.
std::vector<SegmentSeenShare> segmentSeenShares(const std::vector<uint8_t>& seenPerTriangle,
                                                const std::vector<double>& triangleAreaMm2,
                                                const std::vector<std::size_t>& nearestCenterlineIndexPerTriangle,
                                                const std::vector<std::string>& segmentPerPoint);

} // namespace flyover
