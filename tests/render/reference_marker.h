/// @file reference_marker.h
/// @brief The coverage rule of render/coverage.h written out plainly, for the tests: per ray of
///        a view, the hit triangle and, with the footprint, the triangles reached from it over
///        shared edges (found by scanning the triangles around each vertex) that face the
///        camera and have a vertex within the ray's footprint radius. This is how ViewMarker
///        marked before its walk was sped up (edge-neighbour rows and normals built once);
///        the tests check that both give the same triangles.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"
#include "render/render_view.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace flyover::test {

/// The triangles around each vertex of a scene.
inline std::vector<std::vector<uint32_t>> trianglesAroundVertices(const RayScene& scene)
{
    std::vector<std::vector<uint32_t>> around(scene.vertexCount());
    for (uint32_t f = 0; f < scene.triangleCount(); ++f)
        for (const uint32_t v : scene.triangle(f)) around[v].push_back(f);
    return around;
}

/// Sorted, unique triangles that `camera` shows by the coverage rule (viewPx x viewPx rays);
/// `around` = trianglesAroundVertices(scene).
inline std::vector<uint32_t> referenceMark(const RayScene& scene, const std::vector<std::vector<uint32_t>>& around,
                                           const Camera& camera, int viewPx, bool ost, bool footprint)
{
    const uint32_t nf = scene.triangleCount();
    auto corner = [&](uint32_t f, int k) { return scene.vertex(scene.triangle(f)[std::size_t(k)]); };

    RenderOptions o;
    o.widthPx = o.heightPx = viewPx;
    o.ost = ost;
    HitImage hits;
    traceHits(scene, camera, o, hits);
    const double spacingAtUnitDepth =
        2.0 * std::tan(0.5 * camera.fovDeg * 3.14159265358979323846 / 180.0) / double(viewPx);
    std::vector<uint32_t> out;
    std::vector<uint8_t> visited(nf, 0);
    std::vector<uint32_t> queue, touched;
    for (int y = 0; y < hits.height; ++y)
        for (int x = 0; x < hits.width; ++x) {
            const std::size_t pix = std::size_t(y) * std::size_t(hits.width) + std::size_t(x);
            const uint32_t id = hits.primId[pix];
            if (id >= nf) continue;
            out.push_back(id);
            if (!footprint) continue;
            const Vec3d dir = pixelDirection(camera, hits.width, hits.height, x + 0.5, y + 0.5);
            const Vec3d hit = camera.position + dir * double(hits.t[pix]);
            const Vec3d ng = normalize(cross(corner(id, 1) - corner(id, 0), corner(id, 2) - corner(id, 0)));
            const double cosine = std::fabs(dot(normalize(dir), ng));
            const double radius = 0.5 * spacingAtUnitDepth * double(hits.t[pix]) / std::max(cosine, 0.25);
            const double r2 = radius * radius;
            for (const uint32_t f : touched) visited[f] = 0;
            touched.assign(1, id);
            visited[id] = 1;
            queue.assign(1, id);
            for (std::size_t q = 0; q < queue.size(); ++q) {
                const auto t = scene.triangle(queue[q]);
                for (int e = 0; e < 3; ++e) {
                    const uint32_t a = t[std::size_t(e)], b = t[std::size_t((e + 1) % 3)];
                    for (const uint32_t g : around[a]) {
                        if (visited[g]) continue;
                        const auto u = scene.triangle(g);
                        if (u[0] != b && u[1] != b && u[2] != b) continue;
                        visited[g] = 1;
                        touched.push_back(g);
                        const Vec3d c0 = corner(g, 0), c1 = corner(g, 1), c2 = corner(g, 2);
                        const bool facing = !ost || dot(c0 - camera.position, cross(c1 - c0, c2 - c0)) < 0.0;
                        const Vec3d d0 = c0 - hit, d1 = c1 - hit, d2 = c2 - hit;
                        const bool near = std::min({dot(d0, d0), dot(d1, d1), dot(d2, d2)}) <= r2;
                        if (!facing || !near) continue;
                        out.push_back(g);
                        queue.push_back(g);
                    }
                }
            }
        }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
}

} // namespace flyover::test
