/// @file view_rays.h
/// @brief The primary rays of one view as 16-wide Embree packets of 4 x 4 pixel tiles: what
///        renderView traces, and what a bench that traces Embree scenes directly should trace.
#pragma once

#include "render/camera.h"

#include <embree3/rtcore.h>

#include <limits>

namespace flyover {

constexpr int PACKET = 4;  ///< 4 x 4 pixel tiles = one 16-wide ray packet
constexpr int LANES = PACKET * PACKET;

/// Everything a tile task needs to generate the rays of one view.
struct ViewRays {
    float origin[3];
    float corner[3], stepX[3], stepY[3];
    float nearMm = 0.f;
    int width = 0, height = 0;

    ViewRays(const Camera& camera, int w, int h) : width(w), height(h)
    {
        // dir(x, y) = corner + stepX * x + stepY * y for image points (x, y) in pixels; equal to
        // pixelDirection(camera, w, h, x, y): dot(dir, forward) == 1.
        const Vec3d c = pixelDirection(camera, w, h, 0.0, 0.0);
        const Vec3d sx = pixelDirection(camera, w, h, 1.0, 0.0) - c;
        const Vec3d sy = pixelDirection(camera, w, h, 0.0, 1.0) - c;
        for (int k = 0; k < 3; ++k) {
            origin[k] = float(camera.position[k]);
            corner[k] = float(c[k]);
            stepX[k] = float(sx[k]);
            stepY[k] = float(sy[k]);
        }
        nearMm = float(camera.nearMm);
    }

    /// Fills the packet for the 4 x 4 tile (tx, ty) at sub-pixel offset (ox, oy).
    void fill(int tx, int ty, float ox, float oy, int* valid, RTCRayHit16& packet) const
    {
        for (int i = 0; i < LANES; ++i) {
            const int px = tx * PACKET + i % PACKET;
            const int py = ty * PACKET + i / PACKET;
            valid[i] = (px < width && py < height) ? -1 : 0;
            const float fx = float(px) + ox, fy = float(py) + oy;
            packet.ray.org_x[i] = origin[0];
            packet.ray.org_y[i] = origin[1];
            packet.ray.org_z[i] = origin[2];
            packet.ray.dir_x[i] = corner[0] + stepX[0] * fx + stepY[0] * fy;
            packet.ray.dir_y[i] = corner[1] + stepX[1] * fx + stepY[1] * fy;
            packet.ray.dir_z[i] = corner[2] + stepX[2] * fx + stepY[2] * fy;
            packet.ray.tnear[i] = nearMm;
            packet.ray.tfar[i] = std::numeric_limits<float>::infinity();
            packet.ray.time[i] = 0.f;
            packet.ray.mask[i] = 0xFFFFFFFFu;
            packet.ray.id[i] = unsigned(i);
            packet.ray.flags[i] = 0;
            packet.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
            packet.hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
            packet.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
        }
    }
};

} // namespace flyover
