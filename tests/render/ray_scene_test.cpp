#include "render/ray_scene.h"

#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace flyover {
namespace {

using test::makeIcosphere;

constexpr double INF = std::numeric_limits<double>::infinity();
constexpr double FLOAT_EPS = std::numeric_limits<float>::epsilon();

/// Largest gap between a sphere and its inscribed mesh: R minus the smallest distance from
/// the centre to a face plane (the facets' centres sit deepest inside the sphere).
double maxGapToSphere(const TriMesh& mesh, const Vec3d& centre, double radius)
{
    double gap = 0.0;
    for (const auto f : mesh.faces()) {
        std::array<Vec3d, 3> c;
        int k = 0;
        for (const auto v : mesh.fv_range(f)) c[std::size_t(k++)] = test::toVec(mesh.point(v));
        const double planeDistance = std::fabs(dot(c[0] - centre, normalize(test::faceNormal(c))));
        gap = std::max(gap, radius - planeDistance);
    }
    return gap;
}

TEST(TestMeshes, IcosphereWindingIsAsRequested)
{
    const Vec3d centre{1, 2, 3};
    for (const bool inward : {true, false}) {
        const TriMesh mesh = makeIcosphere(centre, 5.0, 2, inward);
        EXPECT_EQ(mesh.n_faces(), 320u);
        for (const auto f : mesh.faces()) {
            std::array<Vec3d, 3> c;
            int k = 0;
            for (const auto v : mesh.fv_range(f)) c[std::size_t(k++)] = test::toVec(mesh.point(v));
            const double d = dot(test::faceNormal(c), (c[0] + c[1] + c[2]) / 3.0 - centre);
            if (inward) EXPECT_LT(d, 0.0);
            else EXPECT_GT(d, 0.0);
        }
    }
}

TEST(RayScene, GeometricNormalIsRightHandedWindingAndOstRejectsItsBackSide)
{
    // One analytic triangle in z = 0 with (v1 - v0) x (v2 - v0) = +z.
    TriMesh mesh = test::buildMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 2}}, false);
    const RayScene scene(mesh);
    EXPECT_EQ(scene.triangleCount(), 1u);

    // From the front side (+z), both modes hit at t = 5 to a few float ULP.
    for (const bool ost : {false, true}) {
        const RayHit h = scene.intersect({0.25, 0.25, 5.0}, {0, 0, -1}, 0.0, INF, ost);
        ASSERT_TRUE(h.hit) << "ost " << ost;
        EXPECT_NEAR(h.t, 5.0, 4 * 5.0 * FLOAT_EPS);
        EXPECT_EQ(h.primId, 0u);
        // Embree's Ng agrees with (v1 - v0) x (v2 - v0): the convention OST relies on.
        EXPECT_NEAR(distance(h.normal, Vec3d(0, 0, 1)), 0.0, 1e-7);
    }
    // From behind: plain rendering sees it, OST discards it.
    const RayHit plain = scene.intersect({0.25, 0.25, -2.0}, {0, 0, 2}, 0.0, INF, false);
    ASSERT_TRUE(plain.hit);
    EXPECT_NEAR(plain.t, 1.0, 4 * FLOAT_EPS);  // t in units of |dir|
    EXPECT_NEAR(distance(plain.normal, Vec3d(0, 0, 1)), 0.0, 1e-7);
    EXPECT_FALSE(scene.intersect({0.25, 0.25, -2.0}, {0, 0, 2}, 0.0, INF, true).hit);

    // tnear and tfar bound the hit.
    EXPECT_FALSE(scene.intersect({0.25, 0.25, 5.0}, {0, 0, -1}, 5.5, INF, false).hit);
    EXPECT_FALSE(scene.intersect({0.25, 0.25, 5.0}, {0, 0, -1}, 0.0, 4.5, false).hit);
    // Misses beside the triangle.
    EXPECT_FALSE(scene.intersect({0.75, 0.75, 5.0}, {0, 0, -1}, 0.0, INF, false).hit);
}

class InwardSphere : public ::testing::Test {
protected:
    static constexpr double R = 10.0;
    static constexpr int LEVEL = 6;  // 81920 faces
    const Vec3d centre{3.0, -4.0, 7.0};
    const TriMesh mesh = makeIcosphere(centre, R, LEVEL, /*inward=*/true);
    const RayScene scene{mesh};
    // Facets lie inside the sphere by at most this gap (~7e-5 R at level 6, far below 0.5% of
    // R); the extra 1e-5 R covers float vertices and Embree's float intersection.
    const double tol = maxGapToSphere(mesh, centre, R) + 1e-5 * R;
};

TEST_F(InwardSphere, FromOutsideOstHitsOnlyTheFarSide)
{
    ASSERT_LT(tol, 0.005 * R);
    for (const double d : {15.0, 30.0, 200.0}) {
        const Vec3d eye = centre + Vec3d{0, 0, d};
        const Vec3d dir{0, 0, -1};
        SCOPED_TRACE("r=" + std::to_string(R) + " d=" + std::to_string(d) + " tol=" + std::to_string(tol));
        const RayHit plain = scene.intersect(eye, dir, 0.0, INF, false);
        ASSERT_TRUE(plain.hit);
        EXPECT_NEAR(plain.t, d - R, tol);
        EXPECT_GT(dot(plain.normal, dir), 0.0);  // near side: inward normal faces away from the eye

        const RayHit ost = scene.intersect(eye, dir, 0.0, INF, true);
        ASSERT_TRUE(ost.hit);
        EXPECT_NEAR(ost.t, d + R, tol);
        EXPECT_LT(dot(ost.normal, dir), 0.0);
    }
    // Off-axis rays through the sphere: OST never returns the near intersection.
    std::mt19937 rng(42);
    std::uniform_real_distribution<double> radial(0.0, 0.8 * R), angle(0.0, 2.0 * PI);
    for (int i = 0; i < 2000; ++i) {
        const Vec3d eye = centre + Vec3d{0, 0, 40.0};
        const double rho = radial(rng), phi = angle(rng);
        const Vec3d target = centre + Vec3d{rho * std::cos(phi), rho * std::sin(phi), 0.0};
        const Vec3d dir = normalize(target - eye);
        // Analytic near and far intersections with the sphere.
        const Vec3d oc = eye - centre;
        const double b = dot(oc, dir), c = dot(oc, oc) - R * R, disc = b * b - c;
        ASSERT_GT(disc, 0.0);
        const double tFar = -b + std::sqrt(disc), tNear = -b - std::sqrt(disc);
        const RayHit h = scene.intersect(eye, dir, 0.0, INF, true);
        ASSERT_TRUE(h.hit) << "seed 42 #" << i;
        EXPECT_NEAR(h.t, tFar, 2.0 * tol) << "seed 42 #" << i << " near=" << tNear;
    }
}

TEST_F(InwardSphere, NearClipWithoutOstHidesTheNearSide)
{
    const double d = 30.0;
    const Vec3d eye = centre + Vec3d{0, 0, d};
    for (const double clip : {d - R + 0.5, d, d + R - 0.5}) {
        const RayHit h = scene.intersect(eye, {0, 0, -1}, clip, INF, false);
        ASSERT_TRUE(h.hit) << "clip " << clip;
        EXPECT_GE(h.t, clip);
        EXPECT_NEAR(h.t, d + R, tol) << "clip " << clip;
    }
    // Clip beyond the far side: nothing left.
    EXPECT_FALSE(scene.intersect(eye, {0, 0, -1}, d + R + 0.5, INF, false).hit);
}

TEST_F(InwardSphere, FromInsideBothModesHitTheWallAtRadius)
{
    std::mt19937 rng(7);
    std::normal_distribution<double> g(0.0, 1.0);
    for (int i = 0; i < 2000; ++i) {
        const Vec3d dir = normalize(Vec3d{g(rng), g(rng), g(rng)});
        const RayHit plain = scene.intersect(centre, dir, 0.0, INF, false);
        const RayHit ost = scene.intersect(centre, dir, 0.0, INF, true);
        ASSERT_TRUE(plain.hit && ost.hit) << "seed 7 #" << i;
        EXPECT_NEAR(plain.t, R, tol) << "seed 7 #" << i;
        EXPECT_LE(plain.t, R + 1e-5 * R);
        EXPECT_EQ(plain.t, ost.t);
        EXPECT_EQ(plain.primId, ost.primId);
        EXPECT_LT(dot(ost.normal, dir), 0.0);  // inward normal faces the viewer inside
    }
}

TEST_F(InwardSphere, RaysThroughSharedEdgesDoNotLeak)
{
    // A ray from inside a closed surface must hit it. Rays aimed exactly at edge midpoints are
    // the hard case for a non-watertight triangle test (without Embree's robust mode about 9%
    // of them slip through); a leak would show as a speckle of background in an OST view.
    int misses = 0;
    for (const auto e : mesh.edges()) {
        const auto h = mesh.halfedge_handle(e, 0);
        const Vec3d mid = (test::toVec(mesh.point(mesh.from_vertex_handle(h))) +
                           test::toVec(mesh.point(mesh.to_vertex_handle(h)))) * 0.5;
        for (const bool ost : {false, true})
            if (!scene.intersect(centre, mid - centre, 0.0, INF, ost).hit) ++misses;
    }
    EXPECT_EQ(misses, 0) << "of " << 2 * mesh.n_edges() << " rays through edge midpoints";
}

TEST_F(InwardSphere, BoundsAndCount)
{
    EXPECT_EQ(scene.triangleCount(), 20u * 4096u);
    EXPECT_NEAR(scene.boundsMin().x, centre.x - R, 1e-5);
    EXPECT_NEAR(scene.boundsMax().y, centre.y + R, 1e-5);
    EXPECT_NEAR(scene.boundsMax().z, centre.z + R, 1e-5);
}

TEST(RayScene, OutwardSphereIsInvisibleFromInsideWithOst)
{
    // The OST counterpart: an outward (ordinary) surface seen from inside shows only back faces.
    const TriMesh mesh = makeIcosphere({0, 0, 0}, 5.0, 3, /*inward=*/false);
    const RayScene scene(mesh);
    EXPECT_TRUE(scene.intersect({0, 0, 0}, {1, 0, 0}, 0.0, INF, false).hit);
    EXPECT_FALSE(scene.intersect({0, 0, 0}, {1, 0, 0}, 0.0, INF, true).hit);
    // ... and from outside OST shows its near side.
    const RayHit h = scene.intersect({0, 0, 20}, {0, 0, -1}, 0.0, INF, true);
    ASSERT_TRUE(h.hit);
    EXPECT_NEAR(h.t, 15.0, 0.01);
}

TEST(RayScene, ArraysGiveTheSameSceneAsTheMesh)
{
    const TriMesh mesh = makeIcosphere({1, 2, 3}, 7.0, 3, true);
    std::vector<float> xyz;
    for (const auto v : mesh.vertices())
        for (int k = 0; k < 3; ++k) xyz.push_back(mesh.point(v)[k]);
    std::vector<uint32_t> tris;
    for (const auto f : mesh.faces())
        for (const auto v : mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
    const RayScene fromMesh(mesh), fromArrays(xyz, tris);
    ASSERT_EQ(fromMesh.triangleCount(), fromArrays.triangleCount());
    ASSERT_EQ(fromMesh.vertexCount(), fromArrays.vertexCount());
    // The mesh path keeps the face-vertex circulator's order (winding and u, v as the mesh).
    for (uint32_t f = 0; f < fromMesh.triangleCount(); ++f)
        EXPECT_EQ(fromMesh.triangle(f), fromArrays.triangle(f)) << "triangle " << f;
    std::mt19937 rng(3);
    std::normal_distribution<double> g(0.0, 1.0);
    for (int i = 0; i < 500; ++i) {
        const Vec3d dir = normalize(Vec3d{g(rng), g(rng), g(rng)});
        const Vec3d eye = Vec3d{1, 2, 3} - dir * 30.0;
        const RayHit a = fromMesh.intersect(eye, dir, 0.0, INF, true);
        const RayHit b = fromArrays.intersect(eye, dir, 0.0, INF, true);
        ASSERT_EQ(a.hit, b.hit);
        EXPECT_EQ(a.t, b.t);
        EXPECT_EQ(a.primId, b.primId);
    }
    EXPECT_THROW(RayScene({0, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 3}), InputError);
    EXPECT_THROW(RayScene({0, 0, 0, 1, 0}, {}), InputError);
}

TEST(RayScene, SmoothNormalsOfASphereAreRadialAndInward)
{
    // Vertex normals of an inward icosphere point to the centre; interpolated ones too, to within
    // the facet angle.
    const Vec3d centre{-2, 5, 1};
    const TriMesh mesh = makeIcosphere(centre, 10.0, 3, true);
    const RayScene scene(mesh);
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0.0, 1.0);
    double maxSmoothRad = 0, maxFlatRad = 0;
    for (int i = 0; i < 1000; ++i) {
        const Vec3d dir = normalize(Vec3d{g(rng), g(rng), g(rng)});
        const RayHit h = scene.intersect(centre, dir, 0.0, INF, true);
        ASSERT_TRUE(h.hit);
        const Vec3d hitPoint = centre + dir * h.t;
        const Vec3d smooth = scene.shadingNormal(h.primId, h.u, h.v, true);
        const Vec3d flat = scene.shadingNormal(h.primId, h.u, h.v, false);
        const Vec3d radialIn = normalize(centre - hitPoint);
        EXPECT_NEAR(length(smooth), 1.0, 1e-6);
        EXPECT_NEAR(distance(flat, h.normal), 0.0, 1e-5);
        maxSmoothRad = std::max(maxSmoothRad, std::acos(std::min(1.0, dot(smooth, radialIn))));
        maxFlatRad = std::max(maxFlatRad, std::acos(std::min(1.0, dot(flat, radialIn))));
    }
    // Level 3: edges span ~0.1 rad. Face normals are off the radial direction by up to about half
    // of that. Vertex normals are area-weighted averages of face normals, which on the uneven
    // triangles of a subdivided icosahedron sit up to ~0.01 rad off radial; interpolating them
    // adds the second-order error (~0.002).
    RecordProperty("maxSmoothRad", std::to_string(maxSmoothRad));
    RecordProperty("maxFlatRad", std::to_string(maxFlatRad));
    EXPECT_LT(maxSmoothRad, 0.015);
    EXPECT_GT(maxFlatRad, 3.0 * maxSmoothRad);
    EXPECT_THROW(scene.shadingNormal(scene.triangleCount(), 0, 0), ParameterError);
}

TEST(RayScene, EmptyMeshNeverHits)
{
    const TriMesh mesh;
    const RayScene scene(mesh);
    EXPECT_EQ(scene.triangleCount(), 0u);
    EXPECT_FALSE(scene.intersect({0, 0, 0}, {1, 0, 0}, 0.0, INF, false).hit);
    EXPECT_FALSE(scene.intersect({0, 0, 0}, {1, 0, 0}, 0.0, INF, true).hit);
}

} // namespace
} // namespace flyover
