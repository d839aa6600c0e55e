/// @file overview.h
/// @brief OST of the whole surface from outside, without navigation (thesis V.C): the six
///        canonical directions of the patient frame, each camera framed to fit the surface,
///        and a marker that shows a centerline position (e.g. the fly-over's current point).
#pragma once

#include "render/camera.h"
#include "render/render_view.h"

#include <array>
#include <cstdint>

namespace flyover {

/// A canonical view direction in the LPS patient frame.
struct CanonicalView {
    const char* name;  ///< "anterior", "posterior", "left", "right", "superior", "inferior"
    Vec3d viewDir;     ///< direction the camera looks along (from the named side towards the body)
    Vec3d up;          ///< view-up: superior for the four side views, anterior for the other two
};

/// The six views, anterior first. The anterior view shows the patient's right on the image's
/// left, as a radiologist reads a frontal image.
const std::array<CanonicalView, 6>& canonicalViews();

/// A marker for one centerline position, drawn over an overview.
struct OverviewMarker {
    Vec3d positionMm;        ///< the centerline point (LPS mm)
    double radiusMm = 10.0;  ///< ring radius: the lumen radius D(p) shows the lumen's extent
    std::array<uint8_t, 3> colour{40, 230, 120};  ///< RGB of ring and dot
    bool centreDot = true;   ///< false: the ring alone (a finding, beside the position marker)
};

/// Draws the marker over `image` (rendered from `camera`): a ring of the projected radius (at
/// least 4 pixels) and, with `centreDot`, a dot at the projected point, always on top (the point lies inside the lumen, behind the
/// transparent near wall). Parts outside the image are clipped; a point behind the camera is
/// not drawn. @throw ParameterError for an image whose buffer does not match its size.
void drawMarker(RgbImage& image, const Camera& camera, const OverviewMarker& marker);

} // namespace flyover
