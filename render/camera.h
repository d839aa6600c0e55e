/// @file camera.h
/// @brief Pinhole cameras: the thesis' fly-over pair (chapter V.A-B), the overview
///        (chapter V.C) and the classic fly-through, all in world LPS millimetres.
#pragma once

#include "volume/centerline_types.h"
#include "volume/vec3.h"

#include <array>

namespace flyover {

/// A pinhole camera. `forward`, `up`, `right` form a right-handed orthonormal frame with
/// right = forward x up... (image x grows along `right`, image y grows along -`up`).
/// Rays are generated with dot(dir, forward) == 1, so t is depth along `forward` and a
/// per-ray tnear == nearMm is exactly a near *plane* at depth nearMm.
struct Camera {
    Vec3d position;
    Vec3d forward{0, 1, 0};
    Vec3d up{0, 0, 1};
    Vec3d right{1, 0, 0};
    double fovDeg = 90.0;   ///< full vertical field of view (degrees)
    double nearMm = 0.0;    ///< near clip plane depth (mm)
};

/// Direction of the ray through the image point (xPx, yPx) of a widthPx x heightPx image:
/// (0, 0) is the top-left corner of the image, pixel (i, j) spans [i, i+1) x [j, j+1), so its
/// centre is (i + 0.5, j + 0.5). `fovDeg` is the vertical field of view; the horizontal one
/// follows from the aspect ratio. Scaled so that dot(dir, forward) == 1: t along it is depth.
Vec3d pixelDirection(const Camera& camera, int widthPx, int heightPx, double xPx, double yPx);

/// Builds a camera at `position` looking at `target` with approximate view-up `upHint`.
Camera lookAt(const Vec3d& position, const Vec3d& target, const Vec3d& upHint, double fovDeg);

struct FlyoverParams {
    double fovDeg = 90.0;            ///< field of view of both cameras (degrees)
    double rollDeg = 0.0;            ///< rotation of both cameras about the centerline (degrees)
    bool leftToRight = true;         ///< travel direction appears left-to-right (false flips)
    double clipOffsetFraction = 0.5; ///< near plane at d - offset, offset = fraction * D(p)
    double clipOffsetMm = -1.0;      ///< if >= 0, the offset in mm (overrides the fraction)
};

/// The two opposite fly-over cameras at a centerline point: positions p ± h·n with
/// h = R/tan(fov/2), both looking at p, view-up perpendicular to tangent and normal so the
/// tangent runs horizontally (left to right unless flipped), near plane at d - offset with
/// offset = clipOffsetFraction · D(p) (or clipOffsetMm).
/// R is `frameRadiusMm`: the half-width the views must frame at the centerline's depth (see
/// flyoverFrameRadii() in render/flyover_path.h, which measures it on the surface); when it is
/// negative, R = D(p), the point's distance to the wall (exact for a round tube).
std::array<Camera, 2> flyoverCameras(const CenterlinePoint& point, const FlyoverParams& params,
                                     double frameRadiusMm = -1.0);

/// The frame vectors of the fly-over pair at `point`: unit tangent t, the rolled normal n
/// (camera 1 looks along -n), and b = t x n, the image's vertical (lateral) axis.
struct FlyoverAxes {
    Vec3d t, n, b;
};
FlyoverAxes flyoverAxes(const CenterlinePoint& point, double rollDeg);

/// The roll (degrees, in (-180, 180]) at which both fly-over cameras of `point` look
/// perpendicular to `directionMm`: a wall point in that direction from the centerline then lies
/// where the two views meet (the cutting line of the classic fly-over's halves).
/// @throw InputError when the direction is parallel to the tangent (it has no such roll).
double cuttingLineRollDeg(const CenterlinePoint& point, const Vec3d& directionMm);

/// A camera outside an axis-aligned box looking along `viewDir` (towards the box centre) with
/// view-up `up`, as close as lets all eight corners project inside a square image with a 4%
/// margin: the whole surface inside the box is framed, tightly for axis-aligned directions.
Camera overviewCamera(const Vec3d& boxMinMm, const Vec3d& boxMaxMm, const Vec3d& viewDir,
                      const Vec3d& up, double fovDeg);

/// The fly-through camera: at the centerline point, looking along +/- tangent.
Camera flythroughCamera(const CenterlinePoint& point, bool forwardDirection, double fovDeg);

} // namespace flyover
