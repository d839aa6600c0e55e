/// @file centerline_types.h
/// @brief The centerline as passed between stages: an ordered polyline from rectum to
///        cecum in world millimetres (LPS). Free of OpenVDB so that render/ can use it.
#pragma once

#include "volume/vec3.h"

#include <cstddef>
#include <string>
#include <vector>

namespace flyover {

struct CenterlinePoint {
    Vec3d positionMm;      ///< world position (LPS mm)
    Vec3d tangent;         ///< unit tangent, pointing from rectum towards cecum
    Vec3d normal;          ///< unit normal, perpendicular to tangent, aligned point to point
                           ///< (thesis V.A) so that fly-over cameras never spin
    double radiusMm = 0;   ///< D(p): distance from the point to the lumen wall (mm)
    bool bridged = false;  ///< true on stretches that bridge a gap between lumen pieces
};

/// A named anatomical point on the path (colon/anatomy_segments.h): the point's index, its
/// arc from the first point and its position.
struct CenterlineLandmark {
    std::string name;  ///< rectosigmoid_junction, descending_sigmoid_junction, splenic_flexure, ...
    std::size_t index = 0;
    double arcMm = 0;
    Vec3d positionMm;
};

struct Centerline {
    std::vector<CenterlinePoint> points;  ///< ordered rectum -> cecum, uniform arc-length step
    double stepMm = 1.0;                  ///< arc-length step between consecutive points (mm)
    /// A narrow tube at the lumen's far end that the path leaves out (the terminal ileum off
    /// the cecum; centerline_far_end.h): its axis from inside the tube, past the mouth, to
    /// its end, about 2 mm apart, and its radius. Empty when nothing was left out. The wall
    /// round it is not the colon's: coverage leaves it out of the wall to see.
    std::vector<Vec3d> leftOutBranchMm;
    double leftOutBranchRadiusMm = 0;
    /// Anatomical segment per point (rectum ... cecum; colon/anatomy_segments.h), empty when
    /// the path was not labelled (an older centerline.json).
    std::vector<std::string> segment;
    std::vector<CenterlineLandmark> landmarks;
    /// "patient" (labelled in the patient frame) or "path only" (frame unknown or at odds
    /// with the path), and why when "path only"; empty when not labelled.
    std::string segmentsFrame;
    std::string segmentsFrameReason;

    double lengthMm() const
    {
        double l = 0;
        for (std::size_t i = 1; i < points.size(); ++i)
            l += distance(points[i].positionMm, points[i - 1].positionMm);
        return l;
    }
};

/// Fills `tangent` (central differences) and `normal` of every point with the thesis'
/// alignment rule (chapter V.A): the first normal is perpendicular to the first segment
/// ((dy, -dx, 0), or (1,0,0) when the segment is along z); each following normal is the
/// previous camera offset carried to the plane through p_i perpendicular to the local
/// segment, i.e. the previous normal with its component along the segment removed, then
/// re-normalised. This is a discrete rotation-minimising frame: it never spins about the
/// path. Positions must be distinct consecutive points.
void computeTangentsAndNormals(Centerline& centerline);

} // namespace flyover
