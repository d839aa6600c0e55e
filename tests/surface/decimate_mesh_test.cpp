// Decimation on its own: budget, bound, guards, topology.
#include "surface/decimate_mesh.h"

#include "surface/extract_surface.h"
#include "surface/mesh_checks.h"
#include "surface/mesh_distance.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <cmath>

namespace flyover {
namespace {

struct Torus {
    double bigR = 10.0, r = 3.5, voxel = 0.5;
    openvdb::FloatGrid::Ptr grid() const
    {
        return test::sampleSdf(
            [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
            openvdb::Vec3d(-bigR - r - 1, -bigR - r - 1, -r - 1), openvdb::Vec3d(bigR + r + 1, bigR + r + 1, r + 1),
            voxel);
    }
};

TEST(DecimateMesh, HalfTheFacesKeepsTopologyOrientationAndShape)
{
    const Torus torus;
    auto grid = torus.grid();
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    const TriMesh original = mesh;
    DecimateParams params;
    params.targetFaces = int64_t(mesh.n_faces() / 2);
    DecimateReport report;
    decimateMesh(mesh, params, &report);
    SCOPED_TRACE("torus R=10 r=3.5 voxel=0.5, " + std::to_string(report.facesBefore) + " -> " +
                 std::to_string(report.facesAfter) + " faces");
    EXPECT_TRUE(report.reachedTarget);
    EXPECT_LE(report.facesAfter, params.targetFaces);
    EXPECT_EQ(report.facesAfter, int64_t(mesh.n_faces()));
    EXPECT_FALSE(mesh.has_face_status());  // attributes released again
    const MeshCheck c = checkMesh(mesh);
    EXPECT_EQ(c.genus, 1);
    EXPECT_EQ(c.components, 1);
    EXPECT_EQ(c.boundaryEdges, 0);
    EXPECT_EQ(c.nonManifoldVertices, 0);
    EXPECT_EQ(c.misorientedComponents, 0);
    EXPECT_EQ(checkFaceOrientation(mesh, *grid).outward, 0);
    // Half the faces of a fine mesh: the quadric keeps the shape well within half a voxel.
    EXPECT_LT(hausdorffDistanceMm(original, mesh, 0.5 * torus.voxel), 0.5 * torus.voxel);
    EXPECT_NEAR(c.enclosedVolumeMm3 / checkMesh(original).enclosedVolumeMm3, 1.0, 0.005);
}

TEST(DecimateMesh, ErrorBoundHoldsForEveryOriginalVertex)
{
    const float voxel = 0.5f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(10.f, openvdb::Vec3f(0.3f), voxel, 3.f);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    const TriMesh original = mesh;
    DecimateParams params;
    params.maxErrorMm = 0.1;
    DecimateReport report;
    decimateMesh(mesh, params, &report);
    EXPECT_GT(report.collapses, 0);
    EXPECT_LT(report.facesAfter, report.facesBefore / 2);
    // The bound is on the original vertices: measure from a face-less copy of them.
    TriMesh vertices;
    for (const auto v : original.vertices()) vertices.add_vertex(original.point(v));
    const SurfaceDistance d = surfaceDistance(vertices, mesh, 1.0);
    ASSERT_EQ(d.samples, int64_t(original.n_vertices()));
    const double worst = d.maxMm;
    EXPECT_LE(worst, params.maxErrorMm * (1 + 1e-4));
    EXPECT_EQ(checkMesh(mesh).genus, 0);
}

TEST(DecimateMesh, GuardCanRefuseEveryCollapse)
{
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    const auto faces = int64_t(mesh.n_faces());
    DecimateParams params;
    params.targetFaces = faces / 2;
    params.acceptTriangle = [](const OpenMesh::Vec3d&, const OpenMesh::Vec3d&, const OpenMesh::Vec3d&) { return false; };
    DecimateReport report;
    decimateMesh(mesh, params, &report);
    EXPECT_EQ(report.collapses, 0);
    EXPECT_FALSE(report.reachedTarget);
    EXPECT_EQ(int64_t(mesh.n_faces()), faces);
}

TEST(DecimateMesh, WithoutBudgetOrBoundNothingHappens)
{
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    const auto faces = mesh.n_faces();
    DecimateReport report;
    decimateMesh(mesh, DecimateParams{}, &report);
    EXPECT_EQ(mesh.n_faces(), faces);
    EXPECT_EQ(report.collapses, 0);
    DecimateParams tooMany;
    tooMany.targetFaces = int64_t(faces) + 10;
    decimateMesh(mesh, tooMany, &report);
    EXPECT_EQ(mesh.n_faces(), faces);
}

TEST(DecimateMesh, OpenTubeKeepsItsBoundaryLoops)
{
    auto grid = test::sampleSdf([](const openvdb::Vec3d& p) { return std::hypot(p.x(), p.y()) - 5.0; },
                                openvdb::Vec3d(-7, -7, -10), openvdb::Vec3d(7, 7, 10), 0.5);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    DecimateParams params;
    params.targetFaces = int64_t(mesh.n_faces() / 2);
    decimateMesh(mesh, params);
    const MeshCheck c = checkMesh(mesh);
    EXPECT_EQ(c.boundaryLoops, 2);
    EXPECT_EQ(c.genus, 0);
    EXPECT_EQ(c.components, 1);
    EXPECT_EQ(c.misorientedComponents, 0);
}

TEST(DecimateMesh, RejectsBadParameters)
{
    TriMesh mesh;
    DecimateParams p;
    p.targetFaces = -1;
    EXPECT_THROW(decimateMesh(mesh, p), ParameterError);
    p = DecimateParams{};
    p.maxErrorMm = std::nan("");
    EXPECT_THROW(decimateMesh(mesh, p), ParameterError);
    p = DecimateParams{};
    p.maxNormalDeviationDeg = 0.0;
    EXPECT_THROW(decimateMesh(mesh, p), ParameterError);
}

} // namespace
} // namespace flyover
