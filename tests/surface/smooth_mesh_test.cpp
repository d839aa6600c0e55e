// Taubin smoothing on its own: what it removes, what it keeps, what it refuses.
#include "surface/smooth_mesh.h"

#include "surface/extract_surface.h"
#include "surface/mesh_checks.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace flyover {
namespace {

/// A flat n x n grid of unit squares in z = 0, each split in two triangles, with interior
/// vertices lifted by seeded uniform noise of +-amplitude.
TriMesh noisyPlane(int n, double amplitude, uint64_t seed)
{
    TriMesh mesh;
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> noise(-amplitude, amplitude);
    std::vector<TriMesh::VertexHandle> v;
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i) {
            const bool interior = i > 0 && j > 0 && i < n && j < n;
            v.push_back(mesh.add_vertex(TriMesh::Point(float(i), float(j), interior ? float(noise(rng)) : 0.f)));
        }
    auto at = [&](int i, int j) { return v[std::size_t(j * (n + 1) + i)]; };
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            mesh.add_face(at(i, j), at(i + 1, j), at(i + 1, j + 1));
            mesh.add_face(at(i, j), at(i + 1, j + 1), at(i, j + 1));
        }
    return mesh;
}

double rmsHeight(const TriMesh& mesh)
{
    double sum = 0;
    for (const auto v : mesh.vertices()) sum += double(mesh.point(v)[2]) * mesh.point(v)[2];
    return std::sqrt(sum / double(mesh.n_vertices()));
}

TEST(TaubinSmoothing, FlattensNoiseAndKeepsTheBoundary)
{
    const uint64_t seed = 11;
    TriMesh mesh = noisyPlane(30, 0.2, seed);
    const TriMesh before = mesh;
    SmoothReport report;
    smoothMeshTaubin(mesh, TaubinParams{}, &report);
    SCOPED_TRACE("noisy plane 30 x 30, amplitude 0.2, seed " + std::to_string(seed));
    // Vertex noise is the highest surface frequency: the default filter damps it several-fold.
    EXPECT_LT(rmsHeight(mesh), 0.25 * rmsHeight(before));
    EXPECT_EQ(report.fixedVertices, 4 * 30);
    for (const auto v : mesh.vertices()) {
        if (mesh.is_boundary(v)) {
            ASSERT_EQ(mesh.point(v), before.point(v)) << "boundary vertex " << v.idx();
        }
    }
    EXPECT_GT(report.maxDisplacementMm, 0.0);
    EXPECT_LE(report.rmsDisplacementMm, report.maxDisplacementMm);
}

TEST(TaubinSmoothing, KeepsASphereItsSize)
{
    // Low frequencies pass: a sphere of 16 voxels radius keeps its volume (plain Laplacian
    // smoothing shrinks it pass after pass). Taubin's transfer function slightly exceeds 1
    // below the pass band, so the sphere grows a little: +0.27% measured after 50 pairs.
    const float r = 8.f, voxel = 0.5f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, openvdb::Vec3f(0.2f), voxel, 3.f);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    const double before = checkMesh(mesh).enclosedVolumeMm3;
    TaubinParams params;
    params.iterations = 50;
    smoothMeshTaubin(mesh, params);
    const MeshCheck after = checkMesh(mesh);
    EXPECT_NEAR(after.enclosedVolumeMm3 / before, 1.0, 0.005);
    EXPECT_EQ(after.genus, 0);
    EXPECT_EQ(after.misorientedComponents, 0);
}

TEST(TaubinSmoothing, ZeroIterationsChangeNothing)
{
    TriMesh mesh = noisyPlane(5, 0.3, 3);
    const TriMesh before = mesh;
    TaubinParams params;
    params.iterations = 0;
    SmoothReport report;
    smoothMeshTaubin(mesh, params, &report);
    for (const auto v : mesh.vertices()) EXPECT_EQ(mesh.point(v), before.point(v));
    EXPECT_EQ(report.maxDisplacementMm, 0.0);
}

TEST(TaubinSmoothing, IsThePlainUmbrellaRuleBitForBit)
{
    // The neighbour lists are built in parallel over the vertices: each interior vertex must
    // still average its own neighbours in circulation order, boundary vertices stay. Reference:
    // the rule written plainly on OpenMesh's circulators, the same arithmetic in the same order.
    // A plane big enough for several parallel chunks (4096 vertices each) and for three of the
    // smoothing's tiles (16384 vertices each, 4 steps per tile), with a hole (a second boundary
    // inside) across the first tiles' border, so that fixed and movable vertices alternate
    // along the rows. 5 iterations: 10 steps, the last tile round takes 2.
    TriMesh mesh = noisyPlane(200, 0.3, 11);
    mesh.request_face_status();
    mesh.request_edge_status();
    mesh.request_vertex_status();
    for (int j = 79; j < 84; ++j)
        for (int i = 40; i < 44; ++i) mesh.delete_face(TriMesh::FaceHandle(2 * (j * 200 + i)), true);
    mesh.garbage_collection();
    ASSERT_GT(mesh.n_vertices(), 2u * 16384u);
    TriMesh expected = mesh;
    TaubinParams params;
    params.iterations = 5;
    using Vec3d = OpenMesh::Vec3d;
    std::vector<Vec3d> p(expected.n_vertices()), tmp(p.size());
    for (const auto v : expected.vertices()) p[std::size_t(v.idx())] = OpenMesh::vector_cast<Vec3d>(expected.point(v));
    int64_t fixed = 0;
    for (const auto v : expected.vertices())
        if (expected.is_boundary(v)) ++fixed;
    auto step = [&](const std::vector<Vec3d>& in, std::vector<Vec3d>& out, double weight) {
        for (const auto v : expected.vertices()) {
            const std::size_t i = std::size_t(v.idx());
            if (expected.is_boundary(v)) {
                out[i] = in[i];
                continue;
            }
            Vec3d mean(0.0);
            for (const auto w : expected.vv_range(v)) mean += in[std::size_t(w.idx())];
            mean /= double(expected.valence(v));
            out[i] = in[i] + weight * (mean - in[i]);
        }
    };
    for (int k = 0; k < params.iterations; ++k) {
        step(p, tmp, params.lambda);
        step(tmp, p, params.mu());
    }
    SmoothReport report;
    smoothMeshTaubin(mesh, params, &report);
    EXPECT_EQ(report.fixedVertices, fixed) << "boundary vertices (outer edge and the hole's rim) left in place";
    EXPECT_GT(fixed, 4 * 200) << "the hole did not open a second boundary";
    for (const auto v : mesh.vertices())
        ASSERT_EQ(mesh.point(v), OpenMesh::vector_cast<TriMesh::Point>(p[std::size_t(v.idx())]))
            << "vertex " << v.idx() << " is not at the plain rule's position";
}

TEST(TaubinSmoothing, MuFollowsThePassBand)
{
    TaubinParams p;
    p.passBand = 0.1;  // lambda 0.5, k_PB 0.1: 1/mu = 0.1 - 2
    EXPECT_NEAR(p.mu(), 1.0 / (0.1 - 2.0), 1e-15);
    EXPECT_LT(p.mu(), -p.lambda);
}

TEST(TaubinSmoothing, RejectsBadParameters)
{
    TriMesh mesh = noisyPlane(3, 0.1, 1);
    TaubinParams p;
    p.iterations = -1;
    EXPECT_THROW(smoothMeshTaubin(mesh, p), ParameterError);
    p = TaubinParams{};
    p.passBand = 1.0;
    EXPECT_THROW(smoothMeshTaubin(mesh, p), ParameterError);
    p.passBand = std::nan("");
    EXPECT_THROW(smoothMeshTaubin(mesh, p), ParameterError);
    p = TaubinParams{};
    p.lambda = 0.0;
    EXPECT_THROW(smoothMeshTaubin(mesh, p), ParameterError);
}

} // namespace
} // namespace flyover
