/// @file flyover_path.h
/// @brief How far the fly-over cameras must stand back at each centerline point.
///
/// The thesis (V.B) places each camera at h = D(p)/tan(fov/2) and calls D "the distance of a
/// given point to the centerline": for a round tube, the lumen radius, which the view then
/// frames exactly at the centerline's depth. A real colon is not round: between haustral folds
/// the wall bulges well beyond the distance from the centerline to the nearest wall (measured
/// on the full phantom: missed pockets 18-28 mm from the centerline where D was 11-18 mm), and
/// a pocket near the cutting line that lies outside both frusta is never seen. So R(p), the
/// half-width each view frames, is measured on the surface: rays fanned from p in its cross-
/// section plane find the wall; a wall point at lateral distance x (along the image's vertical
/// axis b) and depth z beyond the centerline plane (for the camera that sees it with OST) is
/// inside the frustum when x <= R + z·tan(fov/2), so R(p) = max over the fan of
/// x - z·tan(fov/2), at least D(p), plus a 5% margin, capped at 2·D(p) + 5 mm (a ray down a
/// neighbouring stretch at a sharp bend must not zoom the view out). R is then made smooth
/// along the centerline (running maximum over ±8 mm, then a Gaussian of 4 mm), so the
/// elevation changes gently and never spins or jumps. Bridged points (a collapse; p outside
/// the lumen) take D(p) and their neighbours' values through the smoothing.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"
#include "volume/centerline_types.h"

#include <cstdint>
#include <utility>
#include <vector>

namespace flyover {

struct FrameRadiusOptions {
    int fanRays = 72;            ///< rays per cross-section (every 5 degrees)
    double marginFraction = 0.05;
    double windowMm = 8.0;       ///< running maximum over ±windowMm of arc
    double smoothMm = 4.0;       ///< Gaussian sigma after the maximum (mm of arc)
};

/// R(p) for every centerline point (mm), for flyoverCameras(point, params, R).
/// @throw ParameterError for a fov outside (0, 180) or bad options.
std::vector<double> flyoverFrameRadii(const RayScene& scene, const Centerline& centerline,
                                      const FlyoverParams& params, const FrameRadiusOptions& options = {});

/// R(p) of the one centerline point `index`: the very double flyoverFrameRadii()[index] gives
/// (the same rays, maximum and Gaussian, summed in the same order), from the points within
/// frameRadiusReach() only, so that `scene` need hold only frameRadiusTriangles().
/// @throw ParameterError as flyoverFrameRadii, or for an index past the centerline.
double flyoverFrameRadiusAt(const RayScene& scene, const Centerline& centerline, const FlyoverParams& params,
                            std::size_t index, const FrameRadiusOptions& options = {});

/// An axis-aligned box in world mm (for the fan rays' check below).
struct BoxMm {
    Vec3d min, max;
    bool contains(const Vec3d& p) const
    {
        return p.x >= min.x && p.y >= min.y && p.z >= min.z && p.x <= max.x && p.y <= max.y && p.z <= max.z;
    }
};

/// flyoverFrameRadiusAt, and whether every fan ray it cast started inside `box` and met the
/// scene inside it, or spent its reach (4 * cap) without a hit and ended inside it: `within`.
/// Then any scene holding the same triangles inside `box` gives the same R (each ray's segment
/// up to its hit or end lies in the box, which is convex).
double flyoverFrameRadiusAt(const RayScene& scene, const Centerline& centerline, const FlyoverParams& params,
                            std::size_t index, const FrameRadiusOptions& options, const BoxMm& box, bool& within);

/// The first and last centerline index (inclusive) whose fan of rays R(index) depends on: the
/// running maximum's window plus the Gaussian's reach (3 sigma) on either side.
/// @throw ParameterError for an index past the centerline.
std::pair<std::size_t, std::size_t> frameRadiusReach(const Centerline& centerline, std::size_t index,
                                                     const FrameRadiusOptions& options = {});

/// The triangles (three vertex indices each, as in `triangleIndices`, in their order) that a ray
/// of flyoverFrameRadiusAt(index) can meet: those that reach within `marginMm` of the cross-
/// section plane of a point within frameRadiusReach() and of the ball its rays span (radius
/// 4 * cap). Conservative: a triangle is dropped only when all three vertices lie beyond the
/// plane by more than the margin on one side, or when it lies farther from the point than the
/// rays go plus the margin. The margin must cover the rays' float rounding (about 1e-4 mm); a
/// negative one drops triangles that cross the planes (tests show that R then changes).
std::vector<uint32_t> frameRadiusTriangles(const std::vector<float>& verticesXyz,
                                           const std::vector<uint32_t>& triangleIndices,
                                           const Centerline& centerline, const FlyoverParams& params,
                                           std::size_t index, const FrameRadiusOptions& options = {},
                                           double marginMm = 0.05);

/// The triangles (three vertex indices each, in their order) that a primary ray of one of the
/// `cameras` (widthPx x heightPx images, any sub-pixel offset, rays from the near plane on) can
/// meet: a frustum cull. A triangle is dropped only when, for every camera, all three vertices
/// lie outside one of the four side planes or the near plane, each plane moved outwards by
/// `marginMm` (and the sides widened by 0.1% of their slope): the margin covers the rays'
/// float rounding; a negative margin moves the planes inwards (tests show that it then drops
/// what a camera sees).
std::vector<uint32_t> frustumTriangles(const std::vector<float>& verticesXyz,
                                       const std::vector<uint32_t>& triangleIndices,
                                       const std::vector<Camera>& cameras, int widthPx, int heightPx,
                                       double marginMm = 0.25);

} // namespace flyover
