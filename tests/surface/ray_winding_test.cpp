// The ray-crossing winding number (surface/ray_winding.h) against the solid-angle sum, and
// checkMesh's nesting of many voids in one outer surface, which takes the ray path.
#include "surface/ray_winding.h"

#include "surface/extract_surface.h"
#include "surface/mesh_checks.h"
#include "tests/shapes/surface_shapes.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace flyover {
namespace {

using Vec3d = OpenMesh::Vec3d;

/// The oracle: the generalised winding number, a solid-angle sum over every face.
double solidAngleWinding(const TriMesh& mesh, const Vec3d& p)
{
    double sum = 0;
    for (const auto f : mesh.faces()) {
        Vec3d v[3];
        int k = 0;
        for (const auto vh : mesh.fv_range(f)) v[k++] = OpenMesh::vector_cast<Vec3d>(mesh.point(vh)) - p;
        const double la = v[0].norm(), lb = v[1].norm(), lc = v[2].norm();
        const double num = OpenMesh::dot(v[0], OpenMesh::cross(v[1], v[2]));
        const double den = la * lb * lc + OpenMesh::dot(v[0], v[1]) * lc + OpenMesh::dot(v[0], v[2]) * lb +
                           OpenMesh::dot(v[1], v[2]) * la;
        sum += 2.0 * std::atan2(num, den);
    }
    return sum / (4.0 * PI);
}

std::vector<TriMesh::FaceHandle> allFaces(const TriMesh& mesh)
{
    std::vector<TriMesh::FaceHandle> faces;
    for (const auto f : mesh.faces()) faces.push_back(f);
    return faces;
}

TEST(RayWinding, SameIntegerAsTheSolidAngleSumOnALatticeMesh)
{
    // A torus from marching cubes: its vertices lie on the voxel lattice's edges, and the
    // probes are lattice points and the vertices of a second extracted surface, the layout
    // where an axis-aligned ray would run exactly through edges and vertices.
    const double bigR = 6.0, r = 2.0, voxel = 0.5;
    auto torusSdf = test::sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-9), openvdb::Vec3d(9), voxel);
    const TriMesh torus = extractSurface(*torusSdf, MeshParams{});
    auto probeSdf = test::sampleSdf([&](const openvdb::Vec3d& p) { return (p - openvdb::Vec3d(bigR, 0, 0)).length() - 2.6; },
                                    openvdb::Vec3d(-1), openvdb::Vec3d(10), voxel);
    const TriMesh probeMesh = extractSurface(*probeSdf, MeshParams{});
    std::vector<Vec3d> probes;
    for (const auto v : probeMesh.vertices()) probes.push_back(OpenMesh::vector_cast<Vec3d>(probeMesh.point(v)));
    for (double x = -9; x <= 9; x += 1.5)
        for (double y = -9; y <= 9; y += 1.5)
            for (double z = -3; z <= 3; z += 0.5) probes.emplace_back(x, y, z);
    const std::vector<TriMesh::FaceHandle> faces = allFaces(torus);
    const std::vector<RayWindingCounter::Triangle> noCaps;
    const TriMesh reversed = test::flipped(torus);
    const std::vector<TriMesh::FaceHandle> reversedFaces = allFaces(reversed);
    int answered = 0, inside = 0, total = 0;
    for (const auto& dir : RayWindingCounter::directions()) {
        const RayWindingCounter counter(torus, faces, noCaps, dir);
        const RayWindingCounter reversedCounter(reversed, reversedFaces, noCaps, dir);
        for (const Vec3d& p : probes) {
            const double gwn = solidAngleWinding(torus, p);
            const double nearest = std::round(gwn);
            ++total;
            const auto wn = counter.winding(p);
            if (!wn) continue;
            ++answered;
            // An answer is exact: the point is off the surface, so the solid-angle sum is
            // (nearly) that integer too.
            ASSERT_NEAR(gwn, double(*wn), 0.02) << "probe (" << p[0] << ", " << p[1] << ", " << p[2] << ")";
            ASSERT_EQ(*wn, int(nearest));
            const auto back = reversedCounter.winding(p);
            ASSERT_TRUE(back.has_value());
            EXPECT_EQ(*back, -*wn) << "reversed faces give the opposite sign";
            if (*wn != 0) ++inside;
        }
    }
    EXPECT_GE(answered, int(0.95 * total)) << "most probes are far enough from edges to be answered";
    EXPECT_GT(inside, 300) << "probes inside the torus's tube (the probe sphere's vertices there)";
    EXPECT_GT(answered - inside, 300) << "probes outside, the hole included";
}

TEST(RayWinding, OpenSurfaceClosedByCapsAndNoFaces)
{
    // A box without its top face, closed by the two cap triangles of the missing face.
    TriMesh box;
    std::vector<TriMesh::VertexHandle> v;
    for (int i = 0; i < 8; ++i) v.push_back(box.add_vertex(TriMesh::Point(i & 1 ? 2.f : 0.f, i & 2 ? 2.f : 0.f, i & 4 ? 2.f : 0.f)));
    const int quads[5][4] = {{0, 2, 3, 1}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& q : quads) {
        box.add_face(v[std::size_t(q[0])], v[std::size_t(q[1])], v[std::size_t(q[2])]);
        box.add_face(v[std::size_t(q[0])], v[std::size_t(q[2])], v[std::size_t(q[3])]);
    }
    const std::vector<TriMesh::FaceHandle> faces = allFaces(box);
    auto pt = [&](int i) { return OpenMesh::vector_cast<Vec3d>(box.point(v[std::size_t(i)])); };
    const std::vector<RayWindingCounter::Triangle> caps{{pt(4), pt(5), pt(7)}, {pt(4), pt(7), pt(6)}};
    const std::vector<RayWindingCounter::Triangle> noCaps;
    for (const auto& dir : RayWindingCounter::directions()) {
        const RayWindingCounter closed(box, faces, caps, dir);
        EXPECT_EQ(closed.winding(Vec3d(1.1, 0.9, 1.3)).value_or(99), 1) << "outward faces: +1 inside";
        EXPECT_EQ(closed.winding(Vec3d(3.1, 0.9, 1.3)).value_or(99), 0);
        EXPECT_EQ(closed.winding(Vec3d(-5, -5, -5)).value_or(99), 0) << "outside the grid";
        EXPECT_FALSE(closed.winding(Vec3d(1.0, 1.0, 0.0)).has_value()) << "a point on a face: no answer";
        const std::vector<TriMesh::FaceHandle> none;
        const RayWindingCounter empty(box, none, noCaps, dir);
        EXPECT_EQ(empty.winding(Vec3d(1, 1, 1)).value_or(99), 0);
    }
}

TEST(MeshChecks, ManyVoidsInAPartNestOnceAndAnIslandTwice)
{
    // A ball of material (r 20) with 125 spherical voids (r 1.2 on a 5 mm lattice; the centre
    // one r 2.4 holding a solid island of r 1.2): far more probes x faces than the solid-angle
    // sum is used for, so checkMesh counts ray crossings. The "lumen" (negative side) is the
    // material, so the outer sphere has depth 0, the voids 1 and the island 2.
    const double voxel = 0.5;
    auto sdf = test::sampleSdf(
        [](const openvdb::Vec3d& p) {
            double d = p.length() - 20.0;
            for (int i = -2; i <= 2; ++i)
                for (int j = -2; j <= 2; ++j)
                    for (int k = -2; k <= 2; ++k) {
                        const openvdb::Vec3d c(5.0 * i + 0.13, 5.0 * j + 0.21, 5.0 * k + 0.07);
                        const bool centre = i == 0 && j == 0 && k == 0;
                        const double dv = (p - c).length() - (centre ? 2.4 : 1.2);
                        d = std::max(d, -dv);
                        if (centre) d = std::min(d, (p - c).length() - 1.2);
                    }
            return d;
        },
        openvdb::Vec3d(-22), openvdb::Vec3d(22), voxel);
    const TriMesh mesh = extractSurface(*sdf, MeshParams{});
    const MeshCheck c = checkMesh(mesh);
    ASSERT_EQ(c.components, 127);
    ASSERT_GT(double(c.componentList[0].faces) * 126.0, double(1 << 22)) << "the test must take the ray path";
    EXPECT_EQ(c.misorientedComponents, 0);
    int depth[3] = {0, 0, 0};
    for (const auto& comp : c.componentList) {
        ASSERT_GE(comp.nestingDepth, 0);
        ASSERT_LE(comp.nestingDepth, 2);
        ++depth[comp.nestingDepth];
    }
    EXPECT_EQ(depth[0], 1);
    EXPECT_EQ(depth[1], 125);
    EXPECT_EQ(depth[2], 1);
    EXPECT_EQ(c.componentList[0].nestingDepth, 0) << "the outer sphere is the largest";
    // Every component reversed: every sign is wrong for its (unchanged) depth.
    EXPECT_EQ(checkMesh(test::flipped(mesh)).misorientedComponents, 127);
}

} // namespace
} // namespace flyover
