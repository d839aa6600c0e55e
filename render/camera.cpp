#include "render/camera.h"
#include "volume/vec3.h"

#include "volume/error.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace flyover {

namespace {

double radians(double deg) { return deg * PI / 180.0; }

void checkFov(double fovDeg, const char* where)
{
    if (!(fovDeg > 0.0 && fovDeg < 180.0)) {
        std::ostringstream msg;
        msg << where << ": fovDeg must be in (0, 180) degrees, got " << fovDeg;
        throw ParameterError(msg.str());
    }
}

bool isFinite(const Vec3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

/// Completes a frame from a unit forward and an approximate up: right = forward x up, then up
/// re-derived as right x forward so the three are exactly orthonormal.
Camera frameFrom(const Vec3d& position, const Vec3d& forward, const Vec3d& upHint, double fovDeg)
{
    Camera c;
    c.position = position;
    c.forward = normalize(forward);
    Vec3d right = cross(c.forward, upHint);
    if (!(length(right) > 1e-12)) {
        // Up hint parallel to the view direction: any perpendicular will do, pick the world axis
        // least aligned with forward so the result is stable.
        const Vec3d f = c.forward;
        const Vec3d axis = std::fabs(f.z) < 0.9 ? Vec3d{0, 0, 1}
                                                : (std::fabs(f.y) < 0.9 ? Vec3d{0, 1, 0} : Vec3d{1, 0, 0});
        right = cross(f, axis);
    }
    c.right = normalize(right);
    c.up = cross(c.right, c.forward);
    c.fovDeg = fovDeg;
    c.nearMm = 0.0;
    return c;
}

} // namespace

Vec3d pixelDirection(const Camera& camera, int widthPx, int heightPx, double xPx, double yPx)
{
    const double tanHalf = std::tan(0.5 * radians(camera.fovDeg));
    const double aspect = double(widthPx) / double(heightPx);
    const double sx = (2.0 * xPx / widthPx - 1.0) * tanHalf * aspect;
    const double sy = (1.0 - 2.0 * yPx / heightPx) * tanHalf;
    return camera.forward + camera.right * sx + camera.up * sy;
}

Camera lookAt(const Vec3d& position, const Vec3d& target, const Vec3d& upHint, double fovDeg)
{
    checkFov(fovDeg, "lookAt");
    const Vec3d forward = target - position;
    if (!isFinite(position) || !isFinite(target) || !(length(forward) > 0.0)) {
        throw ParameterError("lookAt: position and target must be finite and distinct");
    }
    return frameFrom(position, forward, upHint, fovDeg);
}

FlyoverAxes flyoverAxes(const CenterlinePoint& point, double rollDeg)
{
    const Vec3d t = normalize(point.tangent);
    // Re-orthogonalise the normal against the tangent: centerline files may carry rounding.
    const Vec3d n0 = normalize(point.normal - t * dot(point.normal, t));
    if (!(length(t) > 0.5) || !(length(n0) > 0.5)) {
        throw InputError("flyoverCameras: centerline point has a zero tangent or a normal parallel to it");
    }
    // Roll: rotate n about t (Rodrigues; n is perpendicular to t).
    const double roll = radians(rollDeg);
    const Vec3d n = normalize(n0 * std::cos(roll) + cross(t, n0) * std::sin(roll));
    return FlyoverAxes{t, n, cross(t, n)};
}

std::array<Camera, 2> flyoverCameras(const CenterlinePoint& point, const FlyoverParams& params, double frameRadiusMm)
{
    checkFov(params.fovDeg, "FlyoverParams");
    if (!std::isfinite(params.rollDeg)) throw ParameterError("FlyoverParams.rollDeg must be finite");
    if (!std::isfinite(params.clipOffsetFraction) || !std::isfinite(params.clipOffsetMm)) {
        throw ParameterError("FlyoverParams.clipOffsetFraction/clipOffsetMm must be finite");
    }
    if (!(point.radiusMm >= 0.0) || !std::isfinite(point.radiusMm) || !isFinite(point.positionMm)) {
        std::ostringstream msg;
        msg << "flyoverCameras: centerline point needs a finite position and radiusMm >= 0, got "
               "radiusMm = "
            << point.radiusMm;
        throw InputError(msg.str());
    }
    if (!std::isfinite(frameRadiusMm)) throw InputError("flyoverCameras: frameRadiusMm must be finite");
    const FlyoverAxes axes = flyoverAxes(point, params.rollDeg);
    const Vec3d t = axes.t, n = axes.n;

    const double frame = frameRadiusMm >= 0.0 ? frameRadiusMm : point.radiusMm;
    const double h = frame / std::tan(0.5 * radians(params.fovDeg));
    const double offset =
        params.clipOffsetMm >= 0.0 ? params.clipOffsetMm : params.clipOffsetFraction * point.radiusMm;
    const double nearMm = std::max(0.0, h - offset);

    // right = s·t so that travel runs to image right (s = +1) or left (s = -1); then
    // up = right x forward completes the right-handed frame. Camera 2 is camera 1 turned 180°
    // about the tangent, so both show the same travel direction.
    const double s = params.leftToRight ? 1.0 : -1.0;
    std::array<Camera, 2> cams;
    const Vec3d forwards[2] = {-n, n};
    for (int k = 0; k < 2; ++k) {
        Camera& c = cams[k];
        c.forward = forwards[k];
        c.position = point.positionMm - c.forward * h;
        c.right = t * s;
        c.up = cross(c.right, c.forward);
        c.fovDeg = params.fovDeg;
        c.nearMm = nearMm;
    }
    return cams;
}

double cuttingLineRollDeg(const CenterlinePoint& point, const Vec3d& directionMm)
{
    const Vec3d t = normalize(point.tangent);
    const Vec3d n0 = normalize(point.normal - t * dot(point.normal, t));
    const Vec3d b = cross(t, n0);
    // flyoverCameras rolls the normal to n0 cos(r) + b sin(r); dot with the direction is zero at
    // r = atan2(-a, c) with a = n0 . dir, c = b . dir.
    const double a = dot(n0, directionMm), c = dot(b, directionMm);
    if (!(std::hypot(a, c) > 1e-9 * std::max(1.0, length(directionMm))))
        throw InputError("cuttingLineRollDeg: the direction is parallel to the centerline tangent");
    return std::atan2(-a, c) * 180.0 / PI;
}

Camera overviewCamera(const Vec3d& boxMinMm, const Vec3d& boxMaxMm, const Vec3d& viewDir,
                      const Vec3d& up, double fovDeg)
{
    checkFov(fovDeg, "overviewCamera");
    if (!isFinite(boxMinMm) || !isFinite(boxMaxMm) || !(boxMinMm.x <= boxMaxMm.x) ||
        !(boxMinMm.y <= boxMaxMm.y) || !(boxMinMm.z <= boxMaxMm.z)) {
        throw ParameterError("overviewCamera: the box must be finite with min <= max on every axis");
    }
    if (!isFinite(viewDir) || !(length(viewDir) > 0.0)) {
        throw ParameterError("overviewCamera: viewDir must be a finite non-zero vector");
    }
    const Vec3d centre = (boxMinMm + boxMaxMm) * 0.5;
    const Vec3d dir = normalize(viewDir);
    Camera c = frameFrom(centre, dir, up, fovDeg);
    // Aimed at the box centre, as close as the eight corners allow: a corner at lateral offset
    // a (along right or up) and depth offset z from the centre fits when a <= tan(fov/2) *
    // (dist + z), with a 4% margin. (The image is taken square: the vertical fov is the limit.)
    const double tanHalf = 0.96 * std::tan(0.5 * radians(fovDeg));
    double dist = 0.0;
    for (int k = 0; k < 8; ++k) {
        const Vec3d corner{(k & 1) ? boxMaxMm.x : boxMinMm.x, (k & 2) ? boxMaxMm.y : boxMinMm.y,
                           (k & 4) ? boxMaxMm.z : boxMinMm.z};
        const Vec3d rel = corner - centre;
        const double z = dot(rel, c.forward);
        dist = std::max({dist, std::fabs(dot(rel, c.right)) / tanHalf - z, std::fabs(dot(rel, c.up)) / tanHalf - z,
                         1e-6 - z});
    }
    c.position = centre - c.forward * dist;
    c.nearMm = 0.0;
    return c;
}

Camera flythroughCamera(const CenterlinePoint& point, bool forwardDirection, double fovDeg)
{
    checkFov(fovDeg, "flythroughCamera");
    const Vec3d t = normalize(point.tangent);
    if (!(length(t) > 0.5) || !isFinite(point.positionMm)) {
        throw InputError("flythroughCamera: centerline point has a zero tangent or a non-finite position");
    }
    Camera c = frameFrom(point.positionMm, forwardDirection ? t : -t, point.normal, fovDeg);
    c.nearMm = 0.0;
    return c;
}

} // namespace flyover
