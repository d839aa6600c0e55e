// Surface distances against closed forms and against brute force.
#include "surface/mesh_distance.h"

#include "surface/extract_surface.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace flyover {
namespace {

TriMesh square(float lo, float hi, float z = 0.f)
{
    TriMesh mesh;
    const auto a = mesh.add_vertex({lo, lo, z}), b = mesh.add_vertex({hi, lo, z});
    const auto c = mesh.add_vertex({hi, hi, z}), d = mesh.add_vertex({lo, hi, z});
    mesh.add_face(a, b, c);
    mesh.add_face(a, c, d);
    return mesh;
}

TriMesh sphereMesh(float r, const openvdb::Vec3f& centre, float voxel)
{
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, centre, voxel, 3.f);
    return extractSurface(*grid, MeshParams{});
}

/// Point-to-triangle distance by brute force: the plane projection when it falls inside,
/// else the nearest point on the three edges, each found by clamped projection.
double bruteDistance(const OpenMesh::Vec3d& p, const TriMesh& to)
{
    double best = std::numeric_limits<double>::max();
    for (const auto f : to.faces()) {
        std::array<OpenMesh::Vec3d, 3> t;
        int k = 0;
        for (const auto v : to.fv_range(f)) t[std::size_t(k++)] = OpenMesh::vector_cast<OpenMesh::Vec3d>(to.point(v));
        const OpenMesh::Vec3d n = OpenMesh::cross(t[1] - t[0], t[2] - t[0]).normalized();
        const OpenMesh::Vec3d q = p - OpenMesh::dot(p - t[0], n) * n;
        bool inside = true;
        for (int e = 0; e < 3; ++e)
            inside = inside && OpenMesh::dot(OpenMesh::cross(t[std::size_t((e + 1) % 3)] - t[std::size_t(e)], q - t[std::size_t(e)]), n) >= 0;
        if (inside) {
            best = std::min(best, (p - q).norm());
            continue;
        }
        for (int e = 0; e < 3; ++e) {
            const OpenMesh::Vec3d a = t[std::size_t(e)], ab = t[std::size_t((e + 1) % 3)] - a;
            const double s = std::clamp(OpenMesh::dot(p - a, ab) / ab.sqrnorm(), 0.0, 1.0);
            best = std::min(best, (p - (a + s * ab)).norm());
        }
    }
    return best;
}

TEST(SurfaceDistance, IdenticalMeshesAreZeroApart)
{
    const TriMesh mesh = sphereMesh(5.f, openvdb::Vec3f(0.1f), 0.5f);
    const SurfaceDistance d = surfaceDistance(mesh, mesh, 0.2);
    EXPECT_LT(d.maxMm, 1e-5);
    EXPECT_GT(d.samples, int64_t(mesh.n_vertices() + mesh.n_faces()));
    EXPECT_LT(hausdorffDistanceMm(mesh, mesh, 0.2), 1e-5);
}

TEST(SurfaceDistance, IsOneSided)
{
    // A unit square inside a 3 x 3 square of the same plane: every point of the small one lies
    // on the big one; the big one's corners are sqrt(2) from the small one.
    const TriMesh small = square(0.f, 1.f), big = square(-1.f, 2.f);
    EXPECT_NEAR(surfaceDistance(small, big, 0.05).maxMm, 0.0, 1e-6);
    EXPECT_NEAR(surfaceDistance(big, small, 0.05).maxMm, std::sqrt(2.0), 1e-6);
    EXPECT_NEAR(hausdorffDistanceMm(small, big, 0.05), std::sqrt(2.0), 1e-6);
    // Parallel planes 0.3 apart, over the same square: 0.3 everywhere.
    const SurfaceDistance lifted = surfaceDistance(square(0.f, 1.f, 0.3f), small, 0.05);
    EXPECT_NEAR(lifted.maxMm, 0.3, 1e-6);
    EXPECT_NEAR(lifted.meanMm, 0.3, 1e-6);
}

TEST(SurfaceDistance, ConcentricSpheresAreTheirRadiusDifferenceApart)
{
    const float voxel = 0.25f;
    const TriMesh inner = sphereMesh(6.f, openvdb::Vec3f(0.f), voxel), outer = sphereMesh(6.5f, openvdb::Vec3f(0.f), voxel);
    // Vertices lie within about (h^2 / r) of the true spheres; faces sag inwards by as much.
    const double chord = voxel * voxel / 6.0;
    const SurfaceDistance in = surfaceDistance(inner, outer, voxel), out = surfaceDistance(outer, inner, voxel);
    EXPECT_NEAR(in.meanMm, 0.5, chord);
    EXPECT_NEAR(out.meanMm, 0.5, chord);
    EXPECT_NEAR(std::max(in.maxMm, out.maxMm), 0.5, 2 * chord);
}

TEST(SurfaceDistance, GridSearchAgreesWithBruteForce)
{
    // A spacing larger than every face: the samples are exactly the vertices and the face
    // centroids, which brute force can reproduce. The target sits partly inside and partly
    // far outside the source, so queries start inside and outside the target's grid.
    const TriMesh from = sphereMesh(4.f, openvdb::Vec3f(0.f), 0.5f);
    const TriMesh to = sphereMesh(3.f, openvdb::Vec3f(5.f, 1.f, -2.f), 0.75f);
    const SurfaceDistance d = surfaceDistance(from, to, 100.0);
    ASSERT_EQ(d.samples, int64_t(from.n_vertices() + from.n_faces()));
    double maxD = 0, sum = 0;
    for (const auto v : from.vertices()) {
        const double e = bruteDistance(OpenMesh::vector_cast<OpenMesh::Vec3d>(from.point(v)), to);
        maxD = std::max(maxD, e);
        sum += e;
    }
    for (const auto f : from.faces()) {
        const double e = bruteDistance(OpenMesh::vector_cast<OpenMesh::Vec3d>(from.calc_face_centroid(f)), to);
        maxD = std::max(maxD, e);
        sum += e;
    }
    // Same samples up to the centroid's float rounding (OpenMesh's centroid is in float).
    EXPECT_NEAR(d.maxMm, maxD, 1e-5);
    EXPECT_NEAR(d.meanMm, sum / double(d.samples), 1e-5);
}

TEST(SurfaceDistance, RejectsBadInput)
{
    const TriMesh mesh = square(0.f, 1.f);
    EXPECT_THROW(surfaceDistance(mesh, mesh, 0.0), ParameterError);
    EXPECT_THROW(surfaceDistance(mesh, mesh, std::nan("")), ParameterError);
    EXPECT_THROW(surfaceDistance(mesh, TriMesh{}, 1.0), ParameterError);
}

} // namespace
} // namespace flyover
