/// @file centerline_far_end.h
/// @brief The far end of a colon's path: whether it runs into a narrow tube that leaves a wide
///        lumen, as the terminal ileum leaves the cecum when gas refluxes through an open
///        ileocecal valve. Pure geometry on a path and the lumen's depth; no grids.
///
/// The colon ends in its widest part, the cecum (CT colonography: 5-9 cm across), and the
/// terminal ileum leaves its medial wall 5-8 cm above its end, 2-3 cm across. When gas fills
/// more ileum than the cecum is long below the valve, the lumen's farthest end from the rectum
/// is the ileum's: the path turns into the small bowel and skips the cecum below the valve.
/// This finds the narrow stretch at the path's far end; extractCenterline then plugs it and
/// looks for the wide lumen's own end beyond the mouth (it keeps the path when there is none:
/// a narrow cecum, a poorly distended one, is the colon's end).
#pragma once

#include "volume/vec3.h"

#include <functional>
#include <optional>
#include <vector>

namespace flyover {

/// A narrow tube at a path's far end.
struct NarrowFarEnd {
    std::size_t mouthIndex = 0;  ///< last path sample as deep as WIDE_FRACTION of the wide lumen
    double wideDepthMm = 0;      ///< the wide lumen's depth: the deepest sample of the path's last FAR_WINDOW_MM
    double narrowDepthMm = 0;    ///< the tube's: its deepest sample past the mouth's rim
    double lengthMm = 0;         ///< along the path from the mouth to the far end
    Vec3d plugMm;                ///< on the path inside the tube, clear of the mouth
    double plugRadiusMm = 0;     ///< a ball this wide round plugMm cuts the tube across
};

/// How much of the path's far end is searched for the wide lumen: this many mm, or
/// FAR_WINDOW_FRACTION of the path when that is longer (a long gas-filled ileum must not fill
/// the whole window).
inline constexpr double FAR_WINDOW_MM = 600.0;
inline constexpr double FAR_WINDOW_FRACTION = 0.6;
/// A sample is in the wide lumen when at least this fraction of its depth deep.
inline constexpr double WIDE_FRACTION = 0.6;

/// The narrow tube at the far end (back) of `path` (samples well under a voxel apart, ordered
/// rectum first), or nothing: the path must be at least 100 mm long, and the stretch past the
/// last sample deeper than WIDE_FRACTION x the wide depth at least max(30 mm, the wide depth)
/// long, with room for the plug before its end. `depthMm`: the lumen's depth at a point
/// (distance to the wall, mm).
std::optional<NarrowFarEnd> narrowFarEnd(const std::vector<Vec3d>& path,
                                         const std::function<double(const Vec3d&)>& depthMm);

} // namespace flyover
