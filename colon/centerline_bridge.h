/// @file centerline_bridge.h
/// @brief Joining the centerlines of a collapsed colon's lumen pieces into one path: the order
///        and direction in which the pieces are travelled, and the curves that bridge the gaps.
///        Pure geometry in world millimetres; no grids.
///
/// What it does not do: it does not look at the image between the pieces (a bridge is the
/// shortest plausible connection between two piece ends, not a path through tissue), and it
/// drops no piece: every piece it is given is visited once.
#pragma once

#include "volume/vec3.h"

#include <vector>

namespace flyover {

/// The two ends of one piece's centerline with their outward unit tangents (pointing out of
/// the piece, away from its interior).
struct PieceEnds {
    Vec3d frontMm, backMm;      ///< first and last point of the piece's path (LPS mm)
    Vec3d frontOut, backOut;    ///< unit: frontOut points away from the path at its front
};

/// A travel order: piece order[k] is visited k-th, from its back to its front when
/// reversed[k] (its back end is entered first).
struct PieceChain {
    std::vector<int> order;
    std::vector<bool> reversed;
    double costMm = 0;          ///< summed bridge costs (bridgeCostMm)
};

/// Cost of bridging from an exit end (position, outward tangent) to an entry end (position,
/// outward tangent of the entered piece): the gap length plus turnPenaltyMmPerRad times the
/// angles by which the bridge turns away from the exit direction and into the entry
/// direction (both in [0, pi]). A gap whose ends face each other costs its length; a bridge
/// that must double back costs up to 2 pi * turnPenaltyMmPerRad more.
double bridgeCostMm(const Vec3d& exitMm, const Vec3d& exitOut, const Vec3d& entryMm,
                    const Vec3d& entryOut, double turnPenaltyMmPerRad);

/// The chain of least total bridge cost that starts with piece `first` (travelled front to
/// back, or back to front when firstReversed) and visits every piece once. Exact (dynamic
/// programming over subsets) up to 12 pieces; beyond that, greedy: the cheapest next entry
/// from the current exit. Ties go to the lower piece index, so the result is deterministic.
/// @throw std::invalid_argument when `first` is out of range
PieceChain orderPieces(const std::vector<PieceEnds>& pieces, int first, bool firstReversed,
                       double turnPenaltyMmPerRad);

/// The bridge from an exit end to an entry end: a cubic Bezier curve leaving the exit along
/// exitOut and arriving along -entryOut, with control arms of a third of the gap, so the path
/// stays tangent-continuous at both joints. Returned as a polyline from exitMm to entryMm
/// (both included) with chords no longer than maxChordMm (> 0).
std::vector<Vec3d> bridgeCurve(const Vec3d& exitMm, const Vec3d& exitOut, const Vec3d& entryMm,
                               const Vec3d& entryOut, double maxChordMm);

} // namespace flyover
