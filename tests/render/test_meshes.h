/// @file test_meshes.h
/// @brief Analytic test meshes for the renderer tests: icosphere, box, torus, with inward
///        (lumen-like) or outward winding, and a face filter.
#pragma once

#include "surface/mesh_types.h"
#include "volume/vec3.h"
#include "volume/centerline_types.h"

#include <array>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace flyover::test {

/// Circle of radius R in the xy plane, 1 mm steps, radius r: the centerline of a torus lumen.
inline Centerline circleCenterline(double R, double r)
{
    Centerline c;
    c.stepMm = 1.0;
    const int n = int(std::floor(2.0 * PI * R));
    for (int i = 0; i < n; ++i) {
        const double a = double(i) / R;
        CenterlinePoint p;
        p.positionMm = {R * std::cos(a), R * std::sin(a), 0.0};
        p.radiusMm = r;
        c.points.push_back(p);
    }
    computeTangentsAndNormals(c);
    return c;
}

inline TriMesh::Point toPoint(const Vec3d& v) { return TriMesh::Point(float(v.x), float(v.y), float(v.z)); }
inline Vec3d toVec(const TriMesh::Point& p) { return {p[0], p[1], p[2]}; }

/// Builds a mesh from positions and triangles; `flip` reverses every triangle's winding.
inline TriMesh buildMesh(const std::vector<Vec3d>& points, const std::vector<std::array<int, 3>>& tris,
                         bool flip)
{
    TriMesh mesh;
    mesh.reserve(points.size(), tris.size() * 3 / 2, tris.size());
    for (const auto& p : points) mesh.add_vertex(toPoint(p));
    for (const auto& t : tris) {
        const TriMesh::VertexHandle a(t[0]), b(t[1]), c(t[2]);
        if (flip) mesh.add_face(a, c, b);
        else mesh.add_face(a, b, c);
    }
    return mesh;
}

/// Geodesic sphere from a subdivided icosahedron: 20 * 4^subdivisions faces, every vertex on
/// the sphere. `inward` winds faces so that (v1-v0)x(v2-v0) points to the centre (a lumen).
inline TriMesh makeIcosphere(const Vec3d& centre, double radius, int subdivisions, bool inward)
{
    const double g = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<Vec3d> unit = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0},
                               {0, -1, g}, {0, 1, g}, {0, -1, -g}, {0, 1, -g},
                               {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
    for (auto& v : unit) v = normalize(v);
    // Outward (counter-clockwise seen from outside) icosahedron faces.
    std::vector<std::array<int, 3>> tris = {
        {0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
        {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (int s = 0; s < subdivisions; ++s) {
        std::map<std::pair<int, int>, int> midpoints;
        auto midpoint = [&](int a, int b) {
            const auto key = std::make_pair(std::min(a, b), std::max(a, b));
            const auto it = midpoints.find(key);
            if (it != midpoints.end()) return it->second;
            unit.push_back(normalize(unit[std::size_t(a)] + unit[std::size_t(b)]));
            const int id = int(unit.size()) - 1;
            midpoints.emplace(key, id);
            return id;
        };
        std::vector<std::array<int, 3>> next;
        next.reserve(tris.size() * 4);
        for (const auto& t : tris) {
            const int ab = midpoint(t[0], t[1]), bc = midpoint(t[1], t[2]), ca = midpoint(t[2], t[0]);
            next.push_back({t[0], ab, ca});
            next.push_back({t[1], bc, ab});
            next.push_back({t[2], ca, bc});
            next.push_back({ab, bc, ca});
        }
        tris.swap(next);
    }
    std::vector<Vec3d> points;
    points.reserve(unit.size());
    for (const auto& u : unit) points.push_back(centre + u * radius);
    return buildMesh(points, tris, inward);
}

/// Axis-aligned box, each side split into 2 triangles.
inline TriMesh makeBox(const Vec3d& lo, const Vec3d& hi, bool inward)
{
    std::vector<Vec3d> p;
    for (int i = 0; i < 8; ++i)
        p.push_back({(i & 1) ? hi.x : lo.x, (i & 2) ? hi.y : lo.y, (i & 4) ? hi.z : lo.z});
    // Outward winding per side (corner index bits: x = 1, y = 2, z = 4).
    const std::vector<std::array<int, 3>> tris = {
        {0, 2, 3}, {0, 3, 1},  // -z
        {4, 5, 7}, {4, 7, 6},  // +z
        {0, 1, 5}, {0, 5, 4},  // -y
        {2, 6, 7}, {2, 7, 3},  // +y
        {0, 4, 6}, {0, 6, 2},  // -x
        {1, 3, 7}, {1, 7, 5},  // +x
    };
    return buildMesh(p, tris, inward);
}

/// Torus around the z axis through `centre`: major radius R, minor radius r, nu x nv quads
/// (2 * nu * nv triangles).
inline TriMesh makeTorus(const Vec3d& centre, double majorR, double minorR, int nu, int nv, bool inward)
{
    std::vector<Vec3d> points;
    points.reserve(std::size_t(nu) * std::size_t(nv));
    for (int i = 0; i < nu; ++i) {
        const double u = 2.0 * PI * i / nu;
        for (int j = 0; j < nv; ++j) {
            const double v = 2.0 * PI * j / nv;
            const double ring = majorR + minorR * std::cos(v);
            points.push_back(centre + Vec3d{ring * std::cos(u), ring * std::sin(u), minorR * std::sin(v)});
        }
    }
    std::vector<std::array<int, 3>> tris;
    tris.reserve(std::size_t(2 * nu) * std::size_t(nv));
    auto id = [&](int i, int j) { return ((i + nu) % nu) * nv + (j + nv) % nv; };
    for (int i = 0; i < nu; ++i)
        for (int j = 0; j < nv; ++j) {
            // Outward: d/du x d/dv points away from the tube axis.
            tris.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            tris.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    return buildMesh(points, tris, inward);
}

/// Surface of revolution about the z axis: profile radius rho[i] at height z[i], `segments`
/// around, open at both ends. `inward` winds faces so that normals point to the axis (a lumen).
inline TriMesh makeLathe(const std::vector<double>& z, const std::vector<double>& rho, int segments, bool inward)
{
    std::vector<Vec3d> points;
    for (std::size_t i = 0; i < z.size(); ++i)
        for (int j = 0; j < segments; ++j) {
            const double a = 2.0 * PI * j / segments;
            points.push_back({rho[i] * std::cos(a), rho[i] * std::sin(a), z[i]});
        }
    std::vector<std::array<int, 3>> tris;
    auto id = [&](std::size_t i, int j) { return int(i) * segments + (j + segments) % segments; };
    for (std::size_t i = 0; i + 1 < z.size(); ++i)
        for (int j = 0; j < segments; ++j) {
            // Outward for increasing z: d/d(angle) x d/dz points away from the axis.
            tris.push_back({id(i, j), id(i, j + 1), id(i + 1, j + 1)});
            tris.push_back({id(i, j), id(i + 1, j + 1), id(i + 1, j)});
        }
    return buildMesh(points, tris, inward);
}

/// A tube swept along `path` (points about 1 mm apart or closer) with radius `radius[i]` at
/// point i, `segments` around, open at both ends; rings are perpendicular to the local
/// direction, carried along by a rotation-minimising frame. `inward` winds faces so that
/// normals point to the axis (a lumen).
inline TriMesh makeSweptTube(const std::vector<Vec3d>& path, const std::vector<double>& radius, int segments,
                             bool inward)
{
    std::vector<Vec3d> points;
    Vec3d u{0, 0, 0};
    for (std::size_t i = 0; i < path.size(); ++i) {
        const Vec3d a = path[i == 0 ? 0 : i - 1], b = path[std::min(path.size() - 1, i + 1)];
        const Vec3d t = normalize(b - a);
        if (i == 0) u = std::fabs(t.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
        u = normalize(u - t * dot(u, t));
        const Vec3d v = cross(t, u);
        for (int j = 0; j < segments; ++j) {
            const double ang = 2.0 * PI * j / segments;
            points.push_back(path[i] + (u * std::cos(ang) + v * std::sin(ang)) * radius[i]);
        }
    }
    std::vector<std::array<int, 3>> tris;
    auto id = [&](std::size_t i, int j) { return int(i) * segments + (j + segments) % segments; };
    for (std::size_t i = 0; i + 1 < path.size(); ++i)
        for (int j = 0; j < segments; ++j) {
            // (u, v, t) is right-handed: d/d(angle) x d/d(arc) points away from the axis.
            tris.push_back({id(i, j), id(i, j + 1), id(i + 1, j + 1)});
            tris.push_back({id(i, j), id(i + 1, j + 1), id(i + 1, j)});
        }
    return buildMesh(points, tris, inward);
}

/// A straight lumen along z from 0 to `length` (mm) of radius `radius`, with one annular fold
/// (a ridge that narrows the lumen to radius - foldDepth) centred at zFold, `foldWidth` wide.
struct FoldedTube {
    double radius = 10.0, length = 120.0, zFold = 60.0, foldDepth = 5.0, foldWidth = 3.0;
    double rho(double z) const
    {
        const double u = (z - zFold) / (0.5 * foldWidth);
        return std::fabs(u) < 1.0 ? radius - foldDepth * 0.5 * (1.0 + std::cos(PI * u)) : radius;
    }
    TriMesh mesh(double dzMm = 0.25, int segments = 128) const
    {
        std::vector<double> z, r;
        for (double v = 0; v <= length + 1e-9; v += dzMm) {
            z.push_back(v);
            r.push_back(rho(v));
        }
        return test::makeLathe(z, r, segments, /*inward=*/true);
    }
    /// Centerline along the axis, 1 mm steps, radius = distance to the nearest wall.
    Centerline centerline(double margin = 10.0) const
    {
        Centerline c;
        c.stepMm = 1.0;
        for (double v = margin; v <= length - margin + 1e-9; v += 1.0) {
            CenterlinePoint p;
            p.positionMm = {0, 0, v};
            double d = radius;
            for (double w = 0; w <= length; w += 0.1) d = std::min(d, std::hypot(rho(w), w - v));
            p.radiusMm = d;
            c.points.push_back(p);
        }
        computeTangentsAndNormals(c);
        return c;
    }
};

/// A copy of `mesh` with only the faces for which keep(corners) is true (all vertices kept).
inline TriMesh filterFaces(const TriMesh& mesh, const std::function<bool(const std::array<Vec3d, 3>&)>& keep)
{
    TriMesh out;
    for (const auto v : mesh.vertices()) out.add_vertex(mesh.point(v));
    for (const auto f : mesh.faces()) {
        std::array<Vec3d, 3> c;
        std::array<TriMesh::VertexHandle, 3> vh;
        int k = 0;
        for (const auto v : mesh.fv_range(f)) {
            c[std::size_t(k)] = toVec(mesh.point(v));
            vh[std::size_t(k)] = TriMesh::VertexHandle(v.idx());
            ++k;
        }
        if (keep(c)) out.add_face(vh[0], vh[1], vh[2]);
    }
    return out;
}

inline Vec3d faceNormal(const std::array<Vec3d, 3>& c) { return cross(c[1] - c[0], c[2] - c[0]); }

} // namespace flyover::test
