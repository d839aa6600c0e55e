// Topology and measures on hand-built meshes with exact answers, and on extracted shapes.
#include "surface/mesh_checks.h"

#include "surface/extract_surface.h"
#include "tests/shapes/surface_shapes.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

namespace flyover {
namespace {


/// An axis-aligned box [lo, hi] as 12 triangles. inward = true winds every face so that its
/// normal points into the box (a lumen seen from inside); false points them out (an island).
/// `skipTop` leaves out the two faces at z = hi (an open box).
void addBox(TriMesh& mesh, const OpenMesh::Vec3f& lo, const OpenMesh::Vec3f& hi, bool inward, bool skipTop = false)
{
    std::array<TriMesh::VertexHandle, 8> v;
    for (int i = 0; i < 8; ++i)
        v[std::size_t(i)] = mesh.add_vertex(TriMesh::Point(i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]));
    // Quads wound counter-clockwise seen from OUTSIDE (outward normals).
    const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (int q = 0; q < 6; ++q) {
        if (skipTop && q == 1) continue;
        const int* c = quads[q];
        auto add = [&](int a, int b, int d) {
            if (inward) mesh.add_face(v[std::size_t(a)], v[std::size_t(d)], v[std::size_t(b)]);
            else mesh.add_face(v[std::size_t(a)], v[std::size_t(b)], v[std::size_t(d)]);
        };
        add(c[0], c[1], c[2]);
        add(c[0], c[2], c[3]);
    }
}

TEST(MeshChecks, UnitCubeHasExactCountsAndMeasures)
{
    TriMesh mesh;
    addBox(mesh, {0, 0, 0}, {1, 1, 1}, /*inward=*/true);
    const MeshCheck c = checkMesh(mesh);
    EXPECT_EQ(c.vertices, 8);
    EXPECT_EQ(c.edges, 18);
    EXPECT_EQ(c.faces, 12);
    EXPECT_EQ(c.components, 1);
    EXPECT_EQ(c.closedComponents, 1);
    EXPECT_EQ(c.genus, 0);
    EXPECT_EQ(c.boundaryLoops, 0);
    EXPECT_EQ(c.boundaryEdges, 0);
    EXPECT_EQ(c.nonManifoldVertices, 0);
    EXPECT_EQ(c.degenerateFaces, 0);
    EXPECT_EQ(c.misorientedComponents, 0);
    EXPECT_TRUE(c.isManifold());
    EXPECT_TRUE(c.isClosed());
    EXPECT_NEAR(c.areaMm2, 6.0, 1e-12);
    EXPECT_NEAR(c.enclosedVolumeMm3, 1.0, 1e-12);
    ASSERT_EQ(c.componentList.size(), 1u);
    EXPECT_EQ(c.componentList[0].nestingDepth, 0);
    EXPECT_TRUE(c.componentList[0].hasInwardVolumeSign());
    // 12 cube edges at 90 degrees, 6 face diagonals at 0.
    EXPECT_NEAR(meanDihedralAngleDeg(mesh), 60.0, 1e-9);
}

TEST(MeshChecks, OutwardCubeIsMisoriented)
{
    TriMesh mesh;
    addBox(mesh, {0, 0, 0}, {2, 1, 1}, /*inward=*/false);
    const MeshCheck c = checkMesh(mesh);
    EXPECT_NEAR(c.enclosedVolumeMm3, -2.0, 1e-12);
    EXPECT_EQ(c.misorientedComponents, 1);
}

TEST(MeshChecks, OpenBoxHasOneLoopAndACappedVolume)
{
    TriMesh mesh;
    addBox(mesh, {0, 0, 0}, {1, 2, 3}, /*inward=*/true, /*skipTop=*/true);
    const MeshCheck c = checkMesh(mesh);
    EXPECT_EQ(c.faces, 10);
    EXPECT_EQ(c.boundaryLoops, 1);
    EXPECT_EQ(c.boundaryEdges, 4);
    EXPECT_EQ(c.closedComponents, 0);
    EXPECT_FALSE(c.isClosed());
    EXPECT_EQ(c.genus, 0);                       // a disc: chi = 1 = 2 - 0 - 1
    EXPECT_NEAR(c.areaMm2, 22.0 - 2.0, 1e-12);   // the box's area without its 1 x 2 top
    EXPECT_NEAR(c.enclosedVolumeMm3, 6.0, 1e-12);  // the planar loop caps it exactly
    EXPECT_EQ(c.misorientedComponents, 0);
}

TEST(MeshChecks, IslandInsideTheLumenHasTheOppositeSign)
{
    // A lumen box with a solid island inside it: the island's faces also point into the lumen,
    // i.e. out of the island, so its volume is negative at nesting depth 1: both correct.
    TriMesh mesh;
    addBox(mesh, {0, 0, 0}, {10, 10, 10}, /*inward=*/true);
    addBox(mesh, {4, 4, 4}, {6, 6, 6}, /*inward=*/false);
    const MeshCheck c = checkMesh(mesh);
    ASSERT_EQ(c.components, 2);
    EXPECT_EQ(c.componentList[0].nestingDepth, 0);
    EXPECT_EQ(c.componentList[1].nestingDepth, 1);
    EXPECT_NEAR(c.componentList[1].enclosedVolumeMm3, -8.0, 1e-9);
    EXPECT_EQ(c.misorientedComponents, 0);
    EXPECT_NEAR(c.enclosedVolumeMm3, 1000.0 - 8.0, 1e-9);  // the lumen's volume

    // The same island wound the wrong way (normals into the solid) is caught.
    TriMesh wrong;
    addBox(wrong, {0, 0, 0}, {10, 10, 10}, /*inward=*/true);
    addBox(wrong, {4, 4, 4}, {6, 6, 6}, /*inward=*/true);
    EXPECT_EQ(checkMesh(wrong).misorientedComponents, 1);

    // Side by side (not nested), both are lumen pockets: positive volumes expected.
    TriMesh apart;
    addBox(apart, {0, 0, 0}, {1, 1, 1}, /*inward=*/true);
    addBox(apart, {3, 0, 0}, {4, 1, 1}, /*inward=*/false);
    const MeshCheck a = checkMesh(apart);
    EXPECT_EQ(a.components, 2);
    EXPECT_EQ(a.misorientedComponents, 1);
}

TEST(MeshChecks, BowTieVertexIsNonManifold)
{
    // Two triangles that share only a vertex: one vertex with two boundary fans.
    TriMesh mesh;
    const auto c = mesh.add_vertex({0, 0, 0});
    const auto a0 = mesh.add_vertex({1, 0, 0}), a1 = mesh.add_vertex({1, 1, 0});
    const auto b0 = mesh.add_vertex({-1, 0, 0}), b1 = mesh.add_vertex({-1, -1, 0});
    mesh.add_face(c, a0, a1);
    mesh.add_face(c, b0, b1);
    const MeshCheck check = checkMesh(mesh);
    EXPECT_EQ(check.nonManifoldVertices, 1);
    EXPECT_FALSE(check.isManifold());
    EXPECT_EQ(check.components, 2);  // edge-connected components
    // OpenMesh links the two fans' boundaries through the shared vertex into one figure-eight
    // cycle, counted as one loop: loop counts are only meaningful on a manifold mesh.
    EXPECT_EQ(check.boundaryLoops, 1);
}

TEST(MeshChecks, DegenerateFacesAreCounted)
{
    TriMesh mesh;
    const auto a = mesh.add_vertex({0, 0, 0}), b = mesh.add_vertex({1, 0, 0}), c = mesh.add_vertex({2, 0, 0});
    const auto d = mesh.add_vertex({0, 1, 0});
    mesh.add_face(a, b, c);  // collinear: a cap
    mesh.add_face(a, d, b);
    const MeshCheck check = checkMesh(mesh);
    EXPECT_EQ(check.degenerateFaces, 1);
    // A barely valid face is not degenerate: height 1e-4 of its size.
    TriMesh thin;
    thin.add_face(thin.add_vertex({0, 0, 0}), thin.add_vertex({1, 0, 0}), thin.add_vertex({0.5f, 1e-4f, 0}));
    EXPECT_EQ(checkMesh(thin).degenerateFaces, 0);
    EXPECT_TRUE(isDegenerateTriangle(0.0, 1.0));
    EXPECT_TRUE(isDegenerateTriangle(std::nan(""), 1.0));
    EXPECT_FALSE(isDegenerateTriangle(1e-4, 1.0));
}

TEST(MeshChecks, ExtractedSphereAndTorusHaveTheirGenus)
{
    const double voxel = 0.5;
    auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(8.f, openvdb::Vec3f(0.3f), float(voxel), 3.f);
    const MeshCheck s = checkMesh(extractSurface(*sphere, MeshParams{}));
    EXPECT_EQ(s.genus, 0);
    EXPECT_EQ(s.components, 1);
    EXPECT_EQ(s.misorientedComponents, 0);

    const double bigR = 10.0, r = 3.0;
    auto torus = test::sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-14), openvdb::Vec3d(14), voxel);
    const MeshCheck t = checkMesh(extractSurface(*torus, MeshParams{}));
    EXPECT_EQ(t.genus, 1);
    EXPECT_EQ(t.components, 1);
    EXPECT_EQ(t.closedComponents, 1);
    EXPECT_EQ(t.misorientedComponents, 0);
    EXPECT_GT(t.enclosedVolumeMm3, 0.0);
}

TEST(MeshChecks, SphereInsideASphericalShellNestsTwice)
{
    // Lumen = a ball minus a smaller ball minus... three concentric spheres: depths 0, 1, 2.
    auto grid = test::sampleSdf(
        [](const openvdb::Vec3d& p) {
            const double r = p.length();
            // inside for r < 3 or 6 < r < 10
            return std::min(r - 3.0, std::max(r - 10.0, 6.0 - r));
        },
        openvdb::Vec3d(-12), openvdb::Vec3d(12), 0.5);
    const MeshCheck c = checkMesh(extractSurface(*grid, MeshParams{}));
    ASSERT_EQ(c.components, 3);
    EXPECT_EQ(c.misorientedComponents, 0);
    // Largest first: the r = 10 sphere (depth 0), r = 6 (depth 1), r = 3 (depth 2).
    EXPECT_EQ(c.componentList[0].nestingDepth, 0);
    EXPECT_EQ(c.componentList[1].nestingDepth, 1);
    EXPECT_EQ(c.componentList[2].nestingDepth, 2);
    const double expected = 4.0 / 3.0 * PI * (1000.0 - 216.0 + 27.0);
    EXPECT_NEAR(c.enclosedVolumeMm3 / expected, 1.0, 0.01);
}

TEST(MeshChecks, MeasuresAtOtherPositionsAreThoseOfTheMovedMesh)
{
    // measureMesh and meanDihedralAngleDeg with positions given apart (the mesh stage measures
    // the extracted surface after smoothing moved it) must give the figures of a mesh
    // whose vertices are at those positions, bit for bit: several components (nested spheres,
    // an open box whose loop is capped).
    auto grid = test::sampleSdf(
        [](const openvdb::Vec3d& p) {
            const double r = p.length();
            return std::min(r - 3.0, std::max(r - 10.0, 6.0 - r));
        },
        openvdb::Vec3d(-12), openvdb::Vec3d(12), 0.5);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    addBox(mesh, {20, 0, 0}, {21, 2, 3}, /*inward=*/true, /*skipTop=*/true);
    std::vector<TriMesh::Point> moved(mesh.n_vertices());
    for (const auto v : mesh.vertices()) {
        const TriMesh::Point& p = mesh.point(v);
        // A smooth, non-rigid deformation: changes area, volume and angles.
        moved[std::size_t(v.idx())] = TriMesh::Point(p[0] * 1.1f + 0.05f * std::sin(p[1]), p[1] * 0.9f, p[2] + 0.1f * p[0]);
    }
    const MeshMeasures apart = measureMesh(mesh, moved);
    const double apartRoughness = meanDihedralAngleDeg(mesh, moved);
    const MeshCheck before = checkMesh(mesh);
    const double beforeRoughness = meanDihedralAngleDeg(mesh);
    for (const auto v : mesh.vertices()) mesh.set_point(v, moved[std::size_t(v.idx())]);
    const MeshCheck after = checkMesh(mesh);
    ASSERT_EQ(after.components, 4);
    ASSERT_EQ(after.boundaryLoops, 1);
    EXPECT_NE(after.areaMm2, before.areaMm2) << "the deformation should change the area";
    EXPECT_NE(meanDihedralAngleDeg(mesh), beforeRoughness) << "the deformation should change the angles";
    // Sums of parallel reductions may be joined in another order from run to run: equal to
    // the last bits of a double.
    EXPECT_NEAR(apart.areaMm2, after.areaMm2, 1e-12 * after.areaMm2) << "expected the moved mesh's area";
    EXPECT_NEAR(apart.enclosedVolumeMm3, after.enclosedVolumeMm3, 1e-12 * std::abs(after.enclosedVolumeMm3))
        << "expected the moved mesh's enclosed volume";
    EXPECT_NEAR(apartRoughness, meanDihedralAngleDeg(mesh), 1e-12 * apartRoughness)
        << "expected the moved mesh's roughness";
}

} // namespace
} // namespace flyover
