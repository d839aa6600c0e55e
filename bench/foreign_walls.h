/// @file foreign_walls.h
/// @brief How much of the fly-over views' wall belongs to another loop of colon, measured
///        independently of loop-local OST's own owners: a wall point belongs to the centerline
///        point its inward normal line runs through (the first point x + t n, t = 1..60 mm,
///        within half a radius of a centerline point; render/loop_ownership.h uses lines of
///        sight instead). Used by bench/foreign_walls and by the phantom tests.
#pragma once

#include "render/camera.h"
#include "render/coverage.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "volume/centerline_types.h"

#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace flyover::bench {

/// A camera as poses.json writes it (pipeline/camera_json.h's cameraJson).
inline Camera cameraOfJson(const nlohmann::json& j)
{
    auto vec = [](const nlohmann::json& a) {
        return Vec3d{a.at(0).get<double>(), a.at(1).get<double>(), a.at(2).get<double>()};
    };
    Camera c;
    c.position = vec(j.at("position_mm"));
    c.forward = vec(j.at("forward"));
    c.up = vec(j.at("up"));
    c.right = vec(j.at("right"));
    c.fovDeg = j.at("fov_deg").get<double>();
    c.nearMm = j.at("near_mm").get<double>();
    return c;
}

/// Per scene triangle: the arc (mm, index * step of `cl`) of the centerline point its inward
/// normal line runs through; NaN when the line meets none within 60 mm.
inline std::vector<float> normalLineOwners(const RayScene& scene, const Centerline& cl)
{
    const CenterlineLocator locator(cl, 8.0);
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    std::vector<float> owner(scene.triangleCount(), std::numeric_limits<float>::quiet_NaN());
    tbb::parallel_for(tbb::blocked_range<uint32_t>(0, scene.triangleCount(), 1024), [&](const auto& range) {
        for (uint32_t f = range.begin(); f != range.end(); ++f) {
            const auto t = scene.triangle(f);
            const Vec3d a = scene.vertex(t[0]), b = scene.vertex(t[1]), c = scene.vertex(t[2]);
            const Vec3d n = cross(b - a, c - a);
            if (!(length(n) > 0)) continue;
            const Vec3d x = (a + b + c) / 3.0, u = normalize(n);
            for (double s = 1.0; s <= 60.0; s += 1.0) {
                const Vec3d q = x + u * s;
                const std::size_t i = locator.nearest(q);
                if (distance(q, cl.points[i].positionMm) <= 0.5 * std::max(cl.points[i].radiusMm, 2.0)) {
                    owner[f] = float(double(i) * step);
                    break;
                }
            }
        }
    });
    return owner;
}

struct ForeignPixels {
    uint64_t wall = 0;     ///< pixels with a wall
    uint64_t foreign = 0;  ///< of them, a wall whose reference owner is farther than the limit
    uint64_t unknown = 0;  ///< of them, a wall without a reference owner (not in either count)
    double share() const { return wall ? double(foreign) / double(wall) : 0.0; }
};

/// The pixels of `camera` (px x px, OST, with `loop` when active) whose wall's reference owner
/// (`referenceOwners`, arcs on the reference's path) lies more than `limitMm` from `arcMm` (the
/// view's place on that same path).
inline ForeignPixels foreignPixels(const RayScene& scene, const Camera& camera, int px, const LoopWindow& loop,
                                   const std::vector<float>& referenceOwners, double arcMm, double limitMm)
{
    RenderOptions ro;
    ro.widthPx = ro.heightPx = px;
    ro.loop = loop;
    HitImage hits;
    traceHits(scene, camera, ro, hits);
    ForeignPixels out;
    for (std::size_t i = 0; i < hits.primId.size(); ++i) {
        if (!(hits.t[i] >= 0)) continue;
        const float owner = referenceOwners[hits.primId[i]];
        if (std::isnan(owner)) {
            ++out.unknown;
            continue;
        }
        ++out.wall;
        out.foreign += std::fabs(double(owner) - arcMm) > limitMm ? 1 : 0;
    }
    return out;
}

} // namespace flyover::bench
