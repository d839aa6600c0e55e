#include "surface/extract_surface.h"

#include "colon/phantom.h"
#include "surface/mesh_checks.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"
#include "volume/ingest.h"
#include "colon/segment.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <algorithm>
#include <functional>
#include <iomanip>
#include <limits>
#include <vector>
#include <sstream>
#include <string>

namespace flyover {
namespace {

using test::sampleSdf;

std::string describe(const MeshStats& s)
{
    std::ostringstream o;
    o << "V=" << s.vertices << " F=" << s.faces << " components=" << s.components
      << " boundaryEdges=" << s.boundaryEdges << " dropped=" << s.droppedFaces
      << " degenerate=" << s.degenerateFaces << " repairs=" << s.degenerateRepairs
      << " removed=" << s.removedDegenerateFaces << " nonManifoldEdges=" << s.nonManifoldEdges
      << " conflicts=" << s.orientationConflicts
      << " area=" << s.areaMm2 << " volume=" << s.enclosedVolumeMm3
      << " inward=" << s.inwardFraction;
    return o.str();
}

int64_t eulerCharacteristic(const TriMesh& mesh)
{
    return int64_t(mesh.n_vertices()) - int64_t(mesh.n_edges()) + int64_t(mesh.n_faces());
}

/// Relative error allowed for area and volume: volumeToMesh places one vertex per surface
/// voxel, inside the surface of a convex shape by O(h^2 / r), so the deficit scales like
/// (h / r)^2 (0.04% area, 0.07% volume measured at 40 voxels per radius). 1% holds with a wide
/// margin from ~10 voxels per radius of curvature on.
constexpr double REL_TOL = 0.01;

TEST(ExtractSurface, SphereIsClosedGenusZeroInwardWithExactMeasures)
{
    const float r = 10.f, voxel = 0.5f;  // 20 voxels per radius
    const openvdb::Vec3f centre(1.3f, -2.1f, 0.7f);  // off the voxel lattice
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, centre, voxel, 3.f);
    MeshStats s;
    const TriMesh mesh = extractSurface(*grid, MeshParams{}, &s);
    SCOPED_TRACE("sphere r=" + std::to_string(r) + " voxel=" + std::to_string(voxel) + ": " + describe(s));

    EXPECT_EQ(s.vertices, int64_t(mesh.n_vertices()));
    EXPECT_EQ(s.faces, int64_t(mesh.n_faces()));
    EXPECT_GT(s.faces, 1000);
    EXPECT_EQ(s.components, 1);
    EXPECT_EQ(s.boundaryEdges, 0);
    EXPECT_EQ(s.droppedFaces, 0);
    EXPECT_EQ(s.degenerateFaces, 0);
    EXPECT_EQ(s.nonManifoldEdges, 0);
    EXPECT_EQ(s.orientationConflicts, 0);
    EXPECT_EQ(eulerCharacteristic(mesh), 2);  // genus 0
    EXPECT_NEAR(s.areaMm2 / (4.0 * PI * r * r), 1.0, REL_TOL);
    EXPECT_NEAR(s.enclosedVolumeMm3 / (4.0 / 3.0 * PI * r * r * r), 1.0, REL_TOL);
    EXPECT_EQ(s.inwardFraction, 1.0);
    EXPECT_DOUBLE_EQ(s.areaMm2, surfaceAreaMm2(mesh));
    EXPECT_DOUBLE_EQ(s.enclosedVolumeMm3, enclosedVolumeInward(mesh));

    // Independent geometric check of the orientation: every face normal points towards the
    // centre of the sphere (into the lumen).
    for (const auto f : mesh.faces()) {
        const auto n = mesh.calc_face_normal(f);
        const auto c = mesh.calc_face_centroid(f);
        const openvdb::Vec3f toCentre = centre - openvdb::Vec3f(c[0], c[1], c[2]);
        ASSERT_GT(n[0] * toCentre.x() + n[1] * toCentre.y() + n[2] * toCentre.z(), 0.f) << "face " << f.idx();
    }
}

TEST(ExtractSurface, TorusHasGenusOne)
{
    const double bigR = 12.0, r = 4.0, voxel = 0.25;  // 16 voxels across the minor radius
    auto grid = sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-bigR - r - 1, -bigR - r - 1, -r - 1), openvdb::Vec3d(bigR + r + 1, bigR + r + 1, r + 1),
        voxel);
    MeshStats s;
    const TriMesh mesh = extractSurface(*grid, MeshParams{}, &s);
    SCOPED_TRACE("torus R=" + std::to_string(bigR) + " r=" + std::to_string(r) + " voxel=" +
                 std::to_string(voxel) + ": " + describe(s));
    EXPECT_EQ(s.components, 1);
    EXPECT_EQ(s.boundaryEdges, 0);
    EXPECT_EQ(s.droppedFaces, 0);
    EXPECT_EQ(eulerCharacteristic(mesh), 0);  // genus 1
    EXPECT_NEAR(s.areaMm2 / (4.0 * PI * PI * bigR * r), 1.0, REL_TOL);
    EXPECT_NEAR(s.enclosedVolumeMm3 / (2.0 * PI * PI * bigR * r * r), 1.0, REL_TOL);
    EXPECT_EQ(s.inwardFraction, 1.0);
}

TEST(ExtractSurface, TubeOpenAtTheGridBoundsReportsBoundaryEdges)
{
    // A cylinder sampled only for |z| <= 15 mm: volumeToMesh does not close it at the edge of
    // the sampled region, so the mesh is an open tube (an annulus: chi = 0, two boundary loops).
    const double r = 5.0, voxel = 0.5;
    auto grid = sampleSdf([&](const openvdb::Vec3d& p) { return std::hypot(p.x(), p.y()) - r; },
                          openvdb::Vec3d(-8, -8, -15), openvdb::Vec3d(8, 8, 15), voxel);
    MeshStats s;
    const TriMesh mesh = extractSurface(*grid, MeshParams{}, &s);
    SCOPED_TRACE("tube r=" + std::to_string(r) + " voxel=" + std::to_string(voxel) + ": " + describe(s));
    EXPECT_GT(s.boundaryEdges, 0);
    EXPECT_EQ(s.components, 1);
    EXPECT_EQ(eulerCharacteristic(mesh), 0);
    EXPECT_EQ(s.inwardFraction, 1.0);
    // Each end is a loop around the circumference: roughly 2 pi r / voxel edges per loop.
    EXPECT_GT(s.boundaryEdges, int64_t(2 * (2 * PI * r / voxel) * 0.8));
}

TEST(ExtractSurface, TwoSpheresAreTwoComponents)
{
    auto grid = sampleSdf(
        [](const openvdb::Vec3d& p) {
            const double a = (p - openvdb::Vec3d(-8, 0, 0)).length() - 5.0;
            const double b = (p - openvdb::Vec3d(8, 0, 0)).length() - 4.0;
            return std::min(a, b);
        },
        openvdb::Vec3d(-15, -7, -7), openvdb::Vec3d(15, 7, 7), 0.5);
    MeshStats s;
    const TriMesh mesh = extractSurface(*grid, MeshParams{}, &s);
    SCOPED_TRACE(describe(s));
    EXPECT_EQ(s.components, 2);
    EXPECT_EQ(s.boundaryEdges, 0);
    EXPECT_EQ(eulerCharacteristic(mesh), 4);
    EXPECT_NEAR(s.enclosedVolumeMm3 / (4.0 / 3.0 * PI * (125.0 + 64.0)), 1.0, 2 * REL_TOL);
}

TEST(ExtractSurface, OrientationFollowsTheSignNotTheShape)
{
    // The same sphere with the sign flipped (positive inside): the "lumen" is now the outside,
    // so faces must point away from the centre and the inward volume is negative.
    const float r = 8.f, voxel = 0.5f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, openvdb::Vec3f(0.f), voxel, 3.f);
    const float background = grid->background();
    for (auto it = grid->tree().beginValueAll(); it; ++it) it.setValue(-it.getValue());
    grid->tree().root().setBackground(-background, /*updateChildNodes=*/false);

    MeshStats s;
    const TriMesh mesh = extractSurface(*grid, MeshParams{}, &s);
    SCOPED_TRACE(describe(s));
    EXPECT_EQ(s.inwardFraction, 1.0);
    EXPECT_EQ(s.boundaryEdges, 0);
    EXPECT_NEAR(s.enclosedVolumeMm3 / (-4.0 / 3.0 * PI * r * r * r), 1.0, REL_TOL);
    // volumeToMesh emits a few collapsed quads for this grid (coincident corners): they are
    // repaired (edge collapses, no hole left), so every face has a normal.
    EXPECT_GT(s.degenerateRepairs, 0);
    EXPECT_EQ(s.degenerateFaces, 0);
    EXPECT_EQ(s.droppedFaces, 0);
    EXPECT_EQ(eulerCharacteristic(mesh), 2);
    int64_t zeroNormals = 0;
    for (const auto f : mesh.faces()) {
        const auto n = mesh.calc_face_normal(f);
        if (!(n.sqrnorm() > 0.f)) {
            ++zeroNormals;
            continue;
        }
        const auto c = mesh.calc_face_centroid(f);
        ASSERT_GT(n[0] * c[0] + n[1] * c[1] + n[2] * c[2], 0.f) << "face " << f.idx();
    }
    EXPECT_EQ(zeroNormals, 0);
}

TEST(LumenSideTest, ReadsTheLevelSetExactlyAsOpenVdbsBoxSampler)
{
    // The orientation tests read the level set with corners taken from their leaf (for speed:
    // the guard after smoothing classifies every face before the first pair); the values must
    // be GridSampler<ConstAccessor, BoxSampler>'s, bit for bit: at random points, at points on
    // and around the leaves' faces (x, y or z of the lower corner at 7 mod 8, negative
    // coordinates) and outside the band (tiles, background).
    const openvdb::FloatGrid::Ptr sdf = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        6.0f, openvdb::Vec3f(0.3f, -0.2f, 0.1f), 0.37f, 3.0f);
    sdf->transform().postTranslate(openvdb::Vec3d(-0.05, 0.11, 0.02));
    const LumenSideTest side(*sdf);
    const openvdb::FloatGrid::ConstAccessor accessor = sdf->getConstAccessor();
    const openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> reference(
        accessor, sdf->transform());
    std::mt19937 random(7);
    std::uniform_real_distribution<double> within(-8.0, 8.0), fraction(0.0, 1.0);
    int checked = 0, inLeafCorners = 0;
    auto check = [&](const openvdb::Vec3d& index) {
        const openvdb::Vec3d world = sdf->indexToWorld(index);
        const float expected = reference.wsSample(world);
        const float got = side.valueAt(OpenMesh::Vec3d(world.x(), world.y(), world.z()));
        ASSERT_EQ(got, expected) << "at index " << index << ": expected BoxSampler's value";
        ++checked;
        const openvdb::Coord c = openvdb::Coord::floor(sdf->worldToIndex(world));
        if ((c.x() & 7) != 7 && (c.y() & 7) != 7 && (c.z() & 7) != 7 && accessor.probeConstLeaf(c)) ++inLeafCorners;
    };
    for (int n = 0; n < 20000; ++n) {
        const openvdb::Vec3d w(within(random), within(random), within(random));
        check(sdf->worldToIndex(w));
    }
    // Across leaf faces: the lower corner at 6, 7 and 8 mod 8 on each axis, negative included.
    for (int i = -24; i <= 24; i += 8)
        for (int d = -1; d <= 1; ++d)
            for (int n = 0; n < 50; ++n) {
                const double a = double(i + d) + fraction(random), b = 16.0 * fraction(random) - 8.0,
                             e = 16.0 * fraction(random) - 8.0;
                check(openvdb::Vec3d(a, b, e));
                check(openvdb::Vec3d(b, a, e));
                check(openvdb::Vec3d(e, b, a));
            }
    EXPECT_GT(inLeafCorners, checked / 10) << "few samples read their corners from one leaf";
    EXPECT_LT(inLeafCorners, checked) << "no sample needed the tree look-ups";
}

/// The orientation test as it was written before the faster classification (kept here
/// as the reference): the normal against a central difference of six
/// GridSampler<ConstAccessor, BoxSampler>::wsSample values (the transform's virtual
/// worldToIndex, eight tree look-ups each).
FaceSide referenceSide(const openvdb::FloatGrid& sdf, const std::array<openvdb::Vec3d, 3>& p, openvdb::Vec3d* gradient)
{
    const openvdb::FloatGrid::ConstAccessor accessor = sdf.getConstAccessor();
    const openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> sampler(
        accessor, sdf.transform());
    const openvdb::Vec3d voxel = sdf.voxelSize();
    const double h = std::min({voxel[0], voxel[1], voxel[2]});
    const openvdb::Vec3d n = (p[1] - p[0]).cross(p[2] - p[0]);
    const double longest2 =
        std::max({(p[1] - p[0]).lengthSqr(), (p[2] - p[1]).lengthSqr(), (p[0] - p[2]).lengthSqr()});
    if (isDegenerateTriangle(n.length(), longest2)) return FaceSide::Degenerate;
    const openvdb::Vec3d c = (p[0] + p[1] + p[2]) / 3.0;
    openvdb::Vec3d grad;
    for (int a = 0; a < 3; ++a) {
        openvdb::Vec3d e(0.0);
        e[a] = h;
        grad[a] = (double(sampler.wsSample(c + e)) - double(sampler.wsSample(c - e))) / (2.0 * h);
    }
    *gradient = grad;
    if (!(grad.lengthSqr() > 0.0)) return FaceSide::NoGradient;
    return -n.dot(grad) > 0.0 ? FaceSide::Inward : FaceSide::Outward;
}

/// Compares LumenSideTest::classify (side and gradient, bit for bit) with referenceSide on
/// every face of `mesh` and on `randomTriangles` random small triangles around its vertices.
/// @return how many triangles were compared
int64_t expectSameSidesAsReference(const openvdb::FloatGrid& sdf, const TriMesh& mesh, int randomTriangles,
                                   unsigned seed)
{
    const LumenSideTest side(sdf);
    int64_t compared = 0, failures = 0;
    auto compare = [&](const std::array<openvdb::Vec3d, 3>& p, const char* what) {
        openvdb::Vec3d expectedGradient(0.0);
        const FaceSide expected = referenceSide(sdf, p, &expectedGradient);
        OpenMesh::Vec3d got(0.0);
        const FaceSide seen = side.classify(OpenMesh::Vec3d(p[0][0], p[0][1], p[0][2]),
                                            OpenMesh::Vec3d(p[1][0], p[1][1], p[1][2]),
                                            OpenMesh::Vec3d(p[2][0], p[2][1], p[2][2]), &got);
        ++compared;
        const bool same = seen == expected &&
                          (expected == FaceSide::Degenerate ||
                           (got[0] == expectedGradient[0] && got[1] == expectedGradient[1] && got[2] == expectedGradient[2]));
        if (!same && ++failures <= 5)
            ADD_FAILURE() << std::setprecision(17) << what << " (" << p[0] << ", " << p[1] << ", " << p[2] << "): expected side "
                          << int(expected) << " gradient " << expectedGradient << " (reference), saw side "
                          << int(seen) << " gradient (" << got[0] << ", " << got[1] << ", " << got[2] << ")";
    };
    for (const auto f : mesh.faces()) {
        std::array<openvdb::Vec3d, 3> p;
        int k = 0;
        for (const auto v : mesh.fv_range(f)) {
            const TriMesh::Point& q = mesh.point(v);
            p[std::size_t(k++)] = openvdb::Vec3d(q[0], q[1], q[2]);
        }
        compare(p, "face");
    }
    std::mt19937 random(seed);
    const double voxel = sdf.voxelSize()[0];
    std::uniform_real_distribution<double> offset(-2.0 * voxel, 2.0 * voxel);
    std::uniform_int_distribution<int> vertex(0, int(mesh.n_vertices()) - 1);
    for (int n = 0; n < randomTriangles; ++n) {
        const TriMesh::Point& q = mesh.point(TriMesh::VertexHandle(vertex(random)));
        const openvdb::Vec3d base(q[0], q[1], q[2]);
        std::array<openvdb::Vec3d, 3> p;
        for (auto& corner : p) corner = base + openvdb::Vec3d(offset(random), offset(random), offset(random));
        compare(p, "random triangle");
    }
    EXPECT_EQ(failures, 0) << "of " << compared << " triangles";
    return compared;
}

TEST(LumenSideTest, ClassifiesAsTheReferenceOnThePhantomsLumen)
{
    // For speed, the classification reads the six samples of its gradient through an inlined
    // ScaleTranslateMap and from one leaf when they share it; side and gradient must be those
    // of the plain GridSampler code, bit for bit, on a real lumen (the small phantom through
    // ingest and segmentation): every face of its mesh and random triangles around it.
    PhantomParams pp;
    pp.size = PhantomSize::Small;
    pp.seed = 3;
    const Phantom phantom = makePhantom(pp);
    Image3<float> image;
    image.geometry = phantom.ct.geometry;
    image.voxels.assign(phantom.ct.voxels.begin(), phantom.ct.voxels.end());
    const openvdb::FloatGrid::Ptr sdf = segmentLumen(*ingestImage(image, IngestParams{}), SegmentParams{}).sdf;
    ASSERT_TRUE(dynamic_cast<const openvdb::math::ScaleTranslateMap*>(sdf->transform().baseMap().get()))
        << "expected the lumen's transform to be a ScaleTranslateMap (the inlined path), saw "
        << sdf->transform().mapType();
    const TriMesh mesh = extractSurface(*sdf, MeshParams{});
    ASSERT_GT(mesh.n_faces(), 1000u);
    EXPECT_GT(expectSameSidesAsReference(*sdf, mesh, 200000, 11), int64_t(mesh.n_faces()));
}

TEST(LumenSideTest, ClassifiesAsTheReferenceUnderEveryTransform)
{
    // The same comparison on a sphere's level set under a uniform scale-translate, an
    // anisotropic scale-translate (the inlined path), and a rotated and a sheared affine map
    // (the transform's own worldToIndex).
    struct Case {
        const char* name;
        std::function<openvdb::math::Transform::Ptr()> make;
        bool inlined;
    };
    const std::vector<Case> cases = {
        {"uniform scale + translation",
         [] {
             auto t = openvdb::math::Transform::createLinearTransform(0.4);
             t->postTranslate(openvdb::Vec3d(0.13, -0.21, 0.05));
             return t;
         },
         true},
        {"anisotropic scale + translation",
         [] {
             auto t = openvdb::math::Transform::createLinearTransform(1.0);
             t->postScale(openvdb::Vec3d(0.35, 0.42, 0.6));
             t->postTranslate(openvdb::Vec3d(-1.7, 0.3, 2.25));
             return t;
         },
         true},
        {"rotated, anisotropic",
         [] {
             auto t = openvdb::math::Transform::createLinearTransform(1.0);
             t->postScale(openvdb::Vec3d(0.35, 0.42, 0.6));
             t->postRotate(0.4, openvdb::math::Z_AXIS);
             t->postRotate(-0.3, openvdb::math::X_AXIS);
             t->postTranslate(openvdb::Vec3d(0.5, -0.25, 1.0));
             return t;
         },
         false},
        {"sheared",
         [] {
             auto t = openvdb::math::Transform::createLinearTransform(0.45);
             t->postShear(0.2, openvdb::math::X_AXIS, openvdb::math::Y_AXIS);
             return t;
         },
         false},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        // A sphere of radius 12 voxels in index space, then given the case's transform.
        const openvdb::FloatGrid::Ptr sdf =
            openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(12.0f, openvdb::Vec3f(0.4f, -0.3f, 0.2f), 1.0f, 3.0f);
        sdf->setTransform(c.make());
        const bool inlined = dynamic_cast<const openvdb::math::ScaleTranslateMap*>(sdf->transform().baseMap().get());
        ASSERT_EQ(inlined, c.inlined) << "map type " << sdf->transform().mapType();
        const TriMesh mesh = extractSurface(*sdf, MeshParams{});
        ASSERT_GT(mesh.n_faces(), 100u);
        expectSameSidesAsReference(*sdf, mesh, 20000, 5);
    }
}

TEST(InwardFaceFraction, FlippedMeshScoresZero)
{
    // The check can fail: the sphere's mesh with every face reversed is entirely outward.
    const float r = 8.f, voxel = 0.5f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, openvdb::Vec3f(0.f), voxel, 3.f);
    const TriMesh mesh = extractSurface(*grid, MeshParams{});
    TriMesh flipped;
    for (const auto v : mesh.vertices()) flipped.add_vertex(mesh.point(v));
    for (const auto f : mesh.faces()) {
        std::vector<TriMesh::VertexHandle> vs;
        for (const auto v : mesh.fv_range(f)) vs.push_back(TriMesh::VertexHandle(v.idx()));
        flipped.add_face(vs[0], vs[2], vs[1]);
    }
    ASSERT_EQ(flipped.n_faces(), mesh.n_faces());
    EXPECT_EQ(inwardFaceFraction(mesh, *grid), 1.0);
    EXPECT_EQ(inwardFaceFraction(flipped, *grid), 0.0);
    EXPECT_NEAR(enclosedVolumeInward(flipped), -enclosedVolumeInward(mesh), 1e-9 * enclosedVolumeInward(mesh));
    EXPECT_LT(enclosedVolumeInward(flipped), 0.0);
    EXPECT_DOUBLE_EQ(surfaceAreaMm2(flipped), surfaceAreaMm2(mesh));
}

TEST(ExtractSurface, AdaptiveMeshingKeepsTheSphereClosedAndInward)
{
    const float r = 10.f, voxel = 0.5f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        r, openvdb::Vec3f(1.3f, -2.1f, 0.7f), voxel, 3.f);
    MeshStats uniform, adaptive;
    extractSurface(*grid, MeshParams{}, &uniform);
    MeshParams params;
    params.adaptivity = 0.1;
    const TriMesh mesh = extractSurface(*grid, params, &adaptive);
    SCOPED_TRACE("adaptive: " + describe(adaptive));
    EXPECT_LT(adaptive.faces, uniform.faces);
    EXPECT_EQ(adaptive.components, 1);
    EXPECT_EQ(adaptive.boundaryEdges, 0);
    EXPECT_EQ(eulerCharacteristic(mesh), 2);
    EXPECT_EQ(adaptive.inwardFraction, 1.0);
    // Adaptive meshing replaces near-planar patches of many voxels by single polygons, so the
    // chord deficit is that of polygons several voxels wide (measured -2.8% at 0.1).
    EXPECT_NEAR(adaptive.enclosedVolumeMm3 / (4.0 / 3.0 * PI * r * r * r), 1.0, 5 * REL_TOL);
}

TEST(ExtractSurface, SaddleCheckerboardIsMeshedAndEveryFaceAccountedFor)
{
    // A voxel checkerboard: every cell is an ambiguous saddle, the worst case for a mesher and
    // the most likely source of edges OpenMesh would refuse as non-manifold.
    auto grid = openvdb::FloatGrid::create(1.5f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
    auto acc = grid->getAccessor();
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j)
            for (int k = 0; k < 6; ++k) acc.setValue(openvdb::Coord(i, j, k), ((i + j + k) % 2) ? 1.f : -1.f);
    MeshStats s;
    TriMesh mesh;
    ASSERT_NO_THROW(mesh = extractSurface(*grid, MeshParams{}, &s));
    SCOPED_TRACE(describe(s));

    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*grid, points, triangles, quads, 0.0, 0.0);
    // Every triangle volumeToMesh produced is in the mesh, counted as dropped, or removed
    // by the degenerate-face repair.
    EXPECT_EQ(s.faces + s.droppedFaces + s.removedDegenerateFaces, int64_t(triangles.size() + 2 * quads.size()));
    EXPECT_EQ(s.nonManifoldEdges, 0);
    EXPECT_EQ(s.orientationConflicts, 0);
    EXPECT_EQ(s.faces, int64_t(mesh.n_faces()));
    EXPECT_GT(s.components, 1);  // volumeToMesh separates the saddles into closed pieces
    EXPECT_EQ(s.boundaryEdges, 0);
}

TEST(ExtractSurface, NoZeroCrossingIsAnInputError)
{
    // Empty grid.
    auto empty = openvdb::FloatGrid::create(1.5f);
    EXPECT_THROW(extractSurface(*empty, MeshParams{}), InputError);

    // Active voxels, all outside (positive).
    auto outside = openvdb::FloatGrid::create(1.5f);
    outside->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(9)), 1.0f, true);
    EXPECT_THROW(extractSurface(*outside, MeshParams{}), InputError);

    // A sphere asked for an iso-value beyond its band.
    auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    MeshParams far;
    far.isoValueMm = 10.0;
    EXPECT_THROW(extractSurface(*sphere, far), InputError);
    try {
        extractSurface(*empty, MeshParams{});
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("no zero crossing"), std::string::npos) << e.what();
    }
}

TEST(ExtractSurface, RejectsBadParameters)
{
    auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    MeshParams p;
    p.adaptivity = 1.5;
    EXPECT_THROW(extractSurface(*sphere, p), ParameterError);
    p.adaptivity = std::nan("");
    EXPECT_THROW(extractSurface(*sphere, p), ParameterError);
    p = MeshParams{};
    p.isoValueMm = std::numeric_limits<double>::infinity();
    EXPECT_THROW(extractSurface(*sphere, p), ParameterError);
}

class CancelAtOnce : public Progress {
public:
    void update(double, const std::string&) override {}
    bool cancelled() const override { return true; }
};

TEST(ExtractSurface, HonoursCancellation)
{
    auto sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    CancelAtOnce cancel;
    EXPECT_THROW(extractSurface(*sphere, MeshParams{}, nullptr, &cancel), Cancelled);
}

TEST(ExtractSurface, CountsOnlyStatsKeepTheCountsAndTheMesh)
{
    // surfaceStats = false (as the pipeline's mesh stage asks): the same mesh and counts,
    // without the surface-wide measures.
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(8.f, openvdb::Vec3f(0.4f, 0.2f, -0.3f),
                                                                         0.5f, 3.f);
    MeshStats full, counts;
    const TriMesh a = extractSurface(*grid, MeshParams{}, &full);
    const TriMesh b = extractSurface(*grid, MeshParams{}, &counts, nullptr, false);
    ASSERT_EQ(a.n_vertices(), b.n_vertices());
    ASSERT_EQ(a.n_faces(), b.n_faces());
    for (const auto v : a.vertices())
        ASSERT_EQ(a.point(v), b.point(v)) << "vertex " << v.idx() << " differs";
    EXPECT_EQ(counts.vertices, full.vertices);
    EXPECT_EQ(counts.faces, full.faces);
    EXPECT_EQ(counts.boundaryEdges, full.boundaryEdges);
    EXPECT_EQ(counts.droppedFaces, full.droppedFaces);
    EXPECT_EQ(counts.degenerateRepairs, full.degenerateRepairs);
    EXPECT_EQ(counts.removedDegenerateFaces, full.removedDegenerateFaces);
    EXPECT_EQ(counts.nonManifoldEdges, full.nonManifoldEdges);
    EXPECT_EQ(counts.orientationConflicts, full.orientationConflicts);
    EXPECT_GT(full.areaMm2, 0.0);
    EXPECT_EQ(full.components, 1);
    EXPECT_EQ(counts.components, 0) << "expected the surface-wide measures left out";
    EXPECT_EQ(counts.areaMm2, 0.0);
    EXPECT_EQ(counts.enclosedVolumeMm3, 0.0);
    EXPECT_EQ(counts.inwardFraction, 0.0);

    // With the soup handed back, its edge checks are the caller's: the same mesh, the counts
    // left 0, and the soup (every triangle in) gives full's counts.
    MeshStats noSoupChecks;
    std::shared_ptr<const TriangleSoup> soup;
    const TriMesh c = extractSurface(*grid, MeshParams{}, &noSoupChecks, nullptr, false, &soup);
    ASSERT_EQ(c.n_faces(), a.n_faces());
    for (const auto v : a.vertices()) ASSERT_EQ(a.point(v), c.point(v)) << "vertex " << v.idx() << " differs";
    ASSERT_TRUE(soup) << "the triangle soup was not handed back";
    EXPECT_EQ(int64_t(soup->size()), full.faces + full.droppedFaces + full.removedDegenerateFaces);
    EXPECT_EQ(noSoupChecks.faces, full.faces);
    EXPECT_EQ(noSoupChecks.nonManifoldEdges, 0);
    const auto [nonManifold, conflicts] = countSoupEdgeProblems(*soup);
    EXPECT_EQ(nonManifold, full.nonManifoldEdges);
    EXPECT_EQ(conflicts, full.orientationConflicts);
}

TEST(ExtractSurface, SoupEdgeChecksCountFansAndConflicts)
{
    // A square of two triangles wound alike (clean); a third triangle on edge 0-2 makes it
    // non-manifold; a fourth on edge 1-2 traversed 1 -> 2 like the first: a conflict.
    TriangleSoup soup{{0, 1, 2}, {0, 2, 3}};
    EXPECT_EQ(countSoupEdgeProblems(soup), std::make_pair(int64_t(0), int64_t(0)));
    soup.push_back({2, 0, 4});
    EXPECT_EQ(countSoupEdgeProblems(soup), std::make_pair(int64_t(1), int64_t(0)));
    soup.push_back({1, 2, 5});
    EXPECT_EQ(countSoupEdgeProblems(soup), std::make_pair(int64_t(1), int64_t(1)));
}

} // namespace
} // namespace flyover
