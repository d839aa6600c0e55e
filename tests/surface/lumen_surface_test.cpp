// The mesh stage's whole sequence (extract, smooth, decimate, check) on analytic shapes.
#include "surface/lumen_surface.h"

#include "surface/mesh_distance.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

namespace flyover {
namespace {


std::string describe(const LumenSurfaceReport& r)
{
    const MeshCheck& c = r.check;
    std::ostringstream o;
    o << "F=" << c.faces << " components=" << c.components << " genus=" << c.genus << " loops=" << c.boundaryLoops
      << " nonManifoldV=" << c.nonManifoldVertices << " degenerate=" << c.degenerateFaces << " area=" << c.areaMm2
      << " volume=" << c.enclosedVolumeMm3 << " rawVolume=" << r.rawVolumeMm3 << " smoothingChange="
      << r.smoothingVolumeChange << " roughness " << r.rawRoughnessDeg << " -> " << r.smoothedRoughnessDeg
      << " restored=" << r.smoothingRestoredVertices << " inward=" << r.orientation.inward
      << " outward=" << r.orientation.outward << " misoriented=" << c.misorientedComponents;
    return o.str();
}

/// What every lumen surface must satisfy, whatever the shape.
void expectSound(const LumenSurfaceReport& r)
{
    EXPECT_TRUE(r.isSound());
    EXPECT_EQ(r.orientation.outward, 0);
    EXPECT_EQ(r.orientation.noGradient, 0);
    EXPECT_EQ(r.orientation.inward, r.check.faces);  // 100% inward
    EXPECT_EQ(r.check.misorientedComponents, 0);
    EXPECT_EQ(r.check.nonManifoldVertices, 0);
    EXPECT_EQ(r.check.degenerateFaces, 0);
    EXPECT_EQ(r.extraction.droppedFaces, 0);
    EXPECT_EQ(r.extraction.nonManifoldEdges, 0);
    EXPECT_EQ(r.extraction.orientationConflicts, 0);
}

// Tolerances: volumeToMesh puts vertices on the surface, so flat faces cut inside a convex
// surface by about h^2 / (8 r) (a relative area/volume deficit of order (h / r)^2: 0.1% at
// 10 voxels per radius); Taubin's pass band keeps shapes of 10+ voxels (measured change below
// 0.1%). 1% is a wide, resolution-justified bound from 10 voxels per radius of curvature on.
constexpr double LUMEN_REL_TOL = 0.01;

TEST(LumenSurface, SphereMeetsItsClosedForms)
{
    const double r = 10.0, voxel = 0.5;  // 20 voxels per radius
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(float(r), openvdb::Vec3f(1.3f, -2.1f, 0.7f),
                                                                        float(voxel), 3.f);
    LumenSurfaceReport rep;
    makeLumenSurface(*grid, MeshParams{}, &rep);
    SCOPED_TRACE("sphere r=10 voxel=0.5: " + describe(rep));
    expectSound(rep);
    EXPECT_EQ(rep.check.components, 1);
    EXPECT_EQ(rep.check.genus, 0);
    EXPECT_EQ(rep.check.boundaryLoops, 0);
    EXPECT_NEAR(rep.check.areaMm2 / (4 * PI * r * r), 1.0, LUMEN_REL_TOL);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (4.0 / 3.0 * PI * r * r * r), 1.0, LUMEN_REL_TOL);
    EXPECT_LT(std::fabs(rep.smoothingVolumeChange), 0.01);
}

TEST(LumenSurface, TorusMeetsItsClosedForms)
{
    const double bigR = 12.0, r = 4.0, voxel = 0.4;  // 10 voxels across the minor radius
    auto grid = test::sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-bigR - r - 1, -bigR - r - 1, -r - 1), openvdb::Vec3d(bigR + r + 1, bigR + r + 1, r + 1), voxel);
    LumenSurfaceReport rep;
    makeLumenSurface(*grid, MeshParams{}, &rep);
    SCOPED_TRACE("torus R=12 r=4 voxel=0.4: " + describe(rep));
    expectSound(rep);
    EXPECT_EQ(rep.check.components, 1);
    EXPECT_EQ(rep.check.genus, 1);
    EXPECT_EQ(rep.check.boundaryLoops, 0);
    EXPECT_NEAR(rep.check.areaMm2 / (4 * PI * PI * bigR * r), 1.0, LUMEN_REL_TOL);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (2 * PI * PI * bigR * r * r), 1.0, LUMEN_REL_TOL);
}

TEST(LumenSurface, CapsuleTubeMeetsItsClosedForms)
{
    // A closed tube: a segment of length L swept by a ball of radius r.
    const double r = 5.0, halfL = 12.0, voxel = 0.5;  // 10 voxels per radius
    auto grid = test::sampleSdf(
        [&](const openvdb::Vec3d& p) {
            const double z = std::clamp(p.z(), -halfL, halfL);
            return (p - openvdb::Vec3d(0, 0, z)).length() - r;
        },
        openvdb::Vec3d(-r - 2, -r - 2, -halfL - r - 2), openvdb::Vec3d(r + 2, r + 2, halfL + r + 2), voxel);
    LumenSurfaceReport rep;
    makeLumenSurface(*grid, MeshParams{}, &rep);
    SCOPED_TRACE("capsule r=5 L=24 voxel=0.5: " + describe(rep));
    expectSound(rep);
    EXPECT_EQ(rep.check.components, 1);
    EXPECT_EQ(rep.check.genus, 0);
    EXPECT_EQ(rep.check.closedComponents, 1);
    const double L = 2 * halfL;
    EXPECT_NEAR(rep.check.areaMm2 / (2 * PI * r * L + 4 * PI * r * r), 1.0, LUMEN_REL_TOL);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (PI * r * r * L + 4.0 / 3.0 * PI * r * r * r), 1.0, LUMEN_REL_TOL);
}

TEST(LumenSurface, OpenTubeReportsTwoLoopsAndItsCappedVolume)
{
    // An infinite cylinder sampled for |z| <= 20 mm: volumeToMesh leaves it open where the
    // samples end (as where a scan's bounds cut the colon). Smoothing leaves the loops in place.
    const double r = 5.0, voxel = 0.5, halfL = 20.0;
    auto grid = test::sampleSdf([&](const openvdb::Vec3d& p) { return std::hypot(p.x(), p.y()) - r; },
                                openvdb::Vec3d(-8, -8, -halfL), openvdb::Vec3d(8, 8, halfL), voxel);
    LumenSurfaceReport rep;
    const TriMesh mesh = makeLumenSurface(*grid, MeshParams{}, &rep);
    SCOPED_TRACE("open tube r=5 voxel=0.5: " + describe(rep));
    expectSound(rep);
    EXPECT_EQ(rep.check.components, 1);
    EXPECT_EQ(rep.check.genus, 0);
    EXPECT_EQ(rep.check.boundaryLoops, 2);
    EXPECT_EQ(rep.check.closedComponents, 0);
    EXPECT_FALSE(rep.check.isClosed());
    EXPECT_EQ(rep.smoothing.fixedVertices, rep.check.boundaryEdges);  // a loop has as many vertices as edges

    // Away from the open ends the tube is a cylinder: the area of its middle 20 mm.
    double middleArea = 0;
    for (const auto f : mesh.faces()) {
        if (std::fabs(mesh.calc_face_centroid(f)[2]) > 10.0) continue;
        middleArea += mesh.calc_face_area(f);
    }
    EXPECT_NEAR(middleArea / (2 * PI * r * 20.0), 1.0, LUMEN_REL_TOL);
    // The capped volume: the cylinder between the loops, whose last voxel at each end is cut
    // irregularly by the edge of the samples (the loops wander by about a voxel in z and r):
    // allowed 2 voxels of length at each end beyond the usual tolerance.
    double zLo = std::numeric_limits<double>::max(), zHi = -zLo;
    for (const auto v : mesh.vertices()) {
        if (!mesh.is_boundary(v)) continue;
        zLo = std::min(zLo, double(mesh.point(v)[2]));
        zHi = std::max(zHi, double(mesh.point(v)[2]));
    }
    const double L = zHi - zLo;
    EXPECT_GT(L, 2 * halfL - 4 * voxel);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (PI * r * r * L), 1.0, LUMEN_REL_TOL + 4 * voxel / L);
}

TEST(LumenSurface, StaircaseIsSmoothedAwayWithoutShrinking)
{
    // A voxel mask of a sphere as level set (+-h/2): the mesh is a staircase. Taubin must
    // bring its normals close to the sphere's while the volume moves by at most 1%.
    const double r = 10.0, voxel = 0.5;
    const openvdb::Vec3d centre(0.3, -0.2, 0.1);
    auto grid = test::sampleStaircaseSdf([&](const openvdb::Vec3d& p) { return (p - centre).length() - r; },
                                         centre - openvdb::Vec3d(r + 2), centre + openvdb::Vec3d(r + 2), voxel);
    const auto inward = [&](const OpenMesh::Vec3d& p) {
        return OpenMesh::Vec3d(centre.x(), centre.y(), centre.z()) - p;
    };
    MeshParams none;
    none.smoothMethod = "none";
    LumenSurfaceReport rawRep, rep;
    const TriMesh raw = makeLumenSurface(*grid, none, &rawRep);
    const TriMesh smooth = makeLumenSurface(*grid, MeshParams{}, &rep);
    const test::AngleError before = test::normalAngleError(raw, inward), after = test::normalAngleError(smooth, inward);
    SCOPED_TRACE("staircase sphere r=10 voxel=0.5: normal error mean " + std::to_string(before.meanDeg) + " -> " +
                 std::to_string(after.meanDeg) + " deg, max " + std::to_string(before.maxDeg) + " -> " +
                 std::to_string(after.maxDeg) + "; " + describe(rep));
    expectSound(rep);
    EXPECT_GT(before.meanDeg, 8.0);                 // the staircase is there...
    EXPECT_LT(after.meanDeg, 0.4 * before.meanDeg);  // ...and mostly gone
    EXPECT_LT(after.maxDeg, before.maxDeg);
    EXPECT_LT(std::fabs(rep.smoothingVolumeChange), 0.01);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (4.0 / 3.0 * PI * r * r * r), 1.0, 2 * LUMEN_REL_TOL);
    EXPECT_LT(rep.smoothedRoughnessDeg, rep.rawRoughnessDeg);
}

/// A lumen tube of radius 15 mm with a 6 mm polyp on its wall, at the full-size phantom's
/// voxel size (0.78125 mm: 7.7 voxels across the polyp's radius).
struct PolypTube {
    double tubeR = 15.0, halfL = 25.0, polypR = 6.0, voxel = 0.78125;
    openvdb::Vec3d centre() const { return {tubeR, 0.0, 0.0}; }
    double distance(const openvdb::Vec3d& p) const
    {
        const double tube = std::max(std::hypot(p.x(), p.y()) - tubeR, std::fabs(p.z()) - halfL);
        return std::max(tube, polypR - (p - centre()).length());
    }
    test::PolypSite site() const
    {
        test::PolypSite s;
        s.axisMm = OpenMesh::Vec3d(0, 0, 0);
        s.tangent = OpenMesh::Vec3d(0, 0, 1);
        s.outwardDir = OpenMesh::Vec3d(1, 0, 0);
        s.centreMm = OpenMesh::Vec3d(tubeR, 0, 0);
        s.radiusMm = polypR;
        s.tubeRadiusMm = tubeR;
        return s;
    }
    openvdb::Vec3d lo() const { return {-tubeR - 3, -tubeR - 3, -halfL - 3}; }
    openvdb::Vec3d hi() const { return {tubeR + 3, tubeR + 3, halfL + 3}; }
};

TEST(LumenSurface, PolypKeepsItsHeightThroughSmoothingAndDecimation)
{
    const PolypTube shape;
    MeshParams none, half;
    none.smoothMethod = "none";
    half.decimateFraction = 0.5;
    for (const bool staircase : {false, true}) {
        const auto fn = [&](const openvdb::Vec3d& p) { return shape.distance(p); };
        auto grid = staircase ? test::sampleStaircaseSdf(fn, shape.lo(), shape.hi(), shape.voxel)
                              : test::sampleSdf(fn, shape.lo(), shape.hi(), shape.voxel);
        LumenSurfaceReport rawRep, rep, halfRep;
        const TriMesh raw = makeLumenSurface(*grid, none, &rawRep);
        const TriMesh smooth = makeLumenSurface(*grid, MeshParams{}, &rep);
        const TriMesh decimated = makeLumenSurface(*grid, half, &halfRep);
        const double hRaw = test::polypHeightMm(raw, shape.site());
        const double hSmooth = test::polypHeightMm(smooth, shape.site());
        const double hHalf = test::polypHeightMm(decimated, shape.site());
        SCOPED_TRACE(std::string(staircase ? "staircase" : "exact") + " SDF, 6 mm polyp on a 15 mm tube, voxel " +
                     std::to_string(shape.voxel) + ": height raw " + std::to_string(hRaw) + ", smoothed " +
                     std::to_string(hSmooth) + ", decimated " + std::to_string(hHalf) + "; " + describe(rep));
        expectSound(rep);
        expectSound(halfRep);
        EXPECT_NEAR(hRaw, shape.polypR, 0.5 * shape.voxel);
        EXPECT_GE(hSmooth, 0.9 * hRaw);
        EXPECT_LE(hSmooth, 1.1 * hRaw);
        EXPECT_GE(hSmooth, 0.9 * shape.polypR);
        EXPECT_GE(hHalf, 0.9 * shape.polypR);
        EXPECT_LT(std::fabs(rep.smoothingVolumeChange), 0.01);
        EXPECT_LT(halfRep.decimationHausdorffMm, 0.5 * shape.voxel);
    }
}

TEST(LumenSurface, DecimationToHalfKeepsEverythingElse)
{
    const double bigR = 12.0, r = 4.0, voxel = 0.4;
    auto grid = test::sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-bigR - r - 1, -bigR - r - 1, -r - 1), openvdb::Vec3d(bigR + r + 1, bigR + r + 1, r + 1), voxel);
    MeshParams params;
    params.decimateFraction = 0.5;
    LumenSurfaceReport rep;
    makeLumenSurface(*grid, params, &rep);
    SCOPED_TRACE("torus, half the faces: Hausdorff " + std::to_string(rep.decimationHausdorffMm) + " mm; " + describe(rep));
    expectSound(rep);
    EXPECT_TRUE(rep.decimation.reachedTarget);
    EXPECT_NEAR(double(rep.decimation.facesAfter) / double(rep.decimation.facesBefore), 0.5, 0.001);
    EXPECT_EQ(rep.check.genus, 1);
    EXPECT_EQ(rep.check.components, 1);
    EXPECT_GT(rep.decimationHausdorffMm, 0.0);
    EXPECT_LT(rep.decimationHausdorffMm, 0.5 * voxel);
    EXPECT_NEAR(rep.check.enclosedVolumeMm3 / (2 * PI * PI * bigR * r * r), 1.0, LUMEN_REL_TOL);

    // A budget below what the fraction asks wins.
    params.decimateTargetFaces = int(rep.decimation.facesBefore / 4);
    LumenSurfaceReport quarter;
    makeLumenSurface(*grid, params, &quarter, nullptr, /*measureDecimationError=*/false);
    EXPECT_LE(quarter.decimation.facesAfter, params.decimateTargetFaces);
    EXPECT_EQ(quarter.decimationHausdorffMm, 0.0);
    expectSound(quarter);
}

namespace {

/// The counts of a report that the final checks fill in.
std::string orientationCounts(const FaceOrientation& o)
{
    std::ostringstream out;
    out << "inward " << o.inward << " outward " << o.outward << " degenerate " << o.degenerate << " no gradient "
        << o.noGradient;
    return out.str();
}

std::string finalCheckCounts(const LumenSurfaceReport& r)
{
    std::ostringstream out;
    const MeshCheck& c = r.check;
    out << "vertices " << c.vertices << " edges " << c.edges << " faces " << c.faces << " components "
        << c.components << " closed " << c.closedComponents << " genus " << c.genus << " loops "
        << c.boundaryLoops << " boundary edges " << c.boundaryEdges << " non-manifold " << c.nonManifoldVertices
        << " degenerate " << c.degenerateFaces << " misoriented " << c.misorientedComponents << " listed "
        << c.componentList.size() << " inward " << r.orientation.inward << " outward " << r.orientation.outward
        << " no gradient " << r.orientation.noGradient << " sound " << r.isSound();
    return out.str();
}

/// Its measures, which parallel sums give to the last bits only.
void expectSameMeasures(const LumenSurfaceReport& a, const LumenSurfaceReport& b)
{
    auto near = [](double x, double y, const char* what) {
        EXPECT_NEAR(x, y, 1e-9 * std::max(1.0, std::abs(y))) << what;
    };
    near(a.check.areaMm2, b.check.areaMm2, "area");
    near(a.check.enclosedVolumeMm3, b.check.enclosedVolumeMm3, "enclosed volume");
    near(a.smoothedVolumeMm3, b.smoothedVolumeMm3, "smoothed volume");
    near(a.smoothedRoughnessDeg, b.smoothedRoughnessDeg, "smoothed roughness");
    near(a.smoothingVolumeChange, b.smoothingVolumeChange, "volume change");
    near(a.rawAreaMm2, b.rawAreaMm2, "raw area");
    near(a.rawVolumeMm3, b.rawVolumeMm3, "raw volume");
    near(a.rawRoughnessDeg, b.rawRoughnessDeg, "raw roughness");
}

} // namespace

TEST(LumenSurface, FinalChecksMadeLaterGiveTheSameReport)
{
    // The pipeline leaves the final checks until after the first pair: the mesh
    // and every checked figure must be those of the checks made at once.
    const double bigR = 12.0, r = 4.0, voxel = 0.4;
    auto grid = test::sampleSdf(
        [&](const openvdb::Vec3d& p) { return std::hypot(std::hypot(p.x(), p.y()) - bigR, p.z()) - r; },
        openvdb::Vec3d(-bigR - r - 1, -bigR - r - 1, -r - 1), openvdb::Vec3d(bigR + r + 1, bigR + r + 1, r + 1), voxel);
    for (const bool smooth : {true, false}) {
        MeshParams params;
        if (!smooth) params.smoothMethod = "none";
        LumenSurfaceReport now, later;
        const TriMesh a = makeLumenSurface(*grid, params, &now);
        const TriMesh b = makeLumenSurface(*grid, params, &later, nullptr, true, /*deferFinalChecks=*/true);
        SCOPED_TRACE(smooth ? "taubin" : "no smoothing");
        EXPECT_FALSE(now.finalChecksPending);
        ASSERT_TRUE(later.finalChecksPending) << "the final checks were made at once although asked to wait";
        EXPECT_EQ(later.check.faces, 0) << "checked although asked to wait";
        // The raw mesh's measures wait too (they are not needed to render).
        EXPECT_EQ(later.rawAreaMm2, 0.0) << "raw mesh measured although asked to wait";
        EXPECT_EQ(later.rawRoughnessDeg, 0.0) << "raw mesh measured although asked to wait";
        EXPECT_EQ(bool(later.extractedPoints), smooth) << "extracted positions kept only when smoothing moved them";
        // The soup's edge checks wait too, on the soup kept meanwhile (every triangle in).
        ASSERT_TRUE(later.extractedTriangles) << "the extraction's triangle soup was not kept for its checks";
        EXPECT_EQ(int64_t(later.extractedTriangles->size()),
                  later.extraction.faces + later.extraction.droppedFaces + later.extraction.removedDegenerateFaces);
        ASSERT_EQ(a.n_vertices(), b.n_vertices());
        ASSERT_EQ(a.n_faces(), b.n_faces());
        for (const auto v : a.vertices()) ASSERT_EQ(a.point(v), b.point(v)) << "vertex " << v.idx();
        // After smoothing, the guard's pass over every face has counted the final mesh's
        // orientation: the deferred checks keep those counts instead of a second pass.
        EXPECT_EQ(later.orientationCounted, smooth) << "the guard's orientation counts were not handed on";
        checkLumenSurface(b, *grid, later);
        EXPECT_FALSE(later.finalChecksPending);
        EXPECT_FALSE(later.extractedPoints) << "the extracted positions are kept after the checks";
        EXPECT_FALSE(later.extractedTriangles) << "the triangle soup is kept after the checks";
        EXPECT_EQ(later.extraction.nonManifoldEdges, now.extraction.nonManifoldEdges);
        EXPECT_EQ(later.extraction.orientationConflicts, now.extraction.orientationConflicts);
        EXPECT_GT(later.rawAreaMm2, 0.0);
        EXPECT_EQ(finalCheckCounts(later), finalCheckCounts(now));
        EXPECT_EQ(orientationCounts(later.orientation), orientationCounts(checkFaceOrientation(b, *grid)))
            << "expected the counts of a fresh pass over the final mesh";
        EXPECT_EQ(orientationCounts(now.orientation), orientationCounts(checkFaceOrientation(a, *grid)))
            << "expected the counts of a fresh pass over the final mesh";
        expectSameMeasures(later, now);
        EXPECT_GT(later.check.faces, 0);
        expectSound(later);
    }

    // With decimation the smoothed measures come before it: the checks are made at once.
    MeshParams half;
    half.decimateFraction = 0.5;
    LumenSurfaceReport rep;
    makeLumenSurface(*grid, half, &rep, nullptr, false, /*deferFinalChecks=*/true);
    EXPECT_FALSE(rep.finalChecksPending);
    expectSound(rep);
}

TEST(LumenSurface, GuardRestoresFacesTurnedAwayFromTheLumen)
{
    // Smoothing tilts no face of the analytic shapes past the tangent plane (the phantom has a
    // few: see the full-size test), so the guard is driven by hand: one vertex of a sphere of
    // radius 8 slid 1 mm (several edges) along the surface folds part of its fan over.
    const float r = 8.f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, openvdb::Vec3f(0.f), 0.5f, 3.f);
    TriMesh mesh = extractSurface(*grid, MeshParams{});
    std::vector<TriMesh::Point> extracted(mesh.n_vertices());
    for (const auto v : mesh.vertices()) extracted[std::size_t(v.idx())] = mesh.point(v);
    const TriMesh::VertexHandle pushed(17);
    const TriMesh::Point p = mesh.point(pushed);
    const TriMesh::Point tangent = OpenMesh::cross(p, TriMesh::Point(0.f, 0.f, 1.f)).normalized();
    mesh.set_point(pushed, p + tangent * 1.f);
    const TriMesh::VertexHandle other(100);
    mesh.set_point(other, mesh.point(other) * 1.01f);  // moved, but its faces still point inward
    const FaceOrientation before = checkFaceOrientation(mesh, *grid);
    ASSERT_GT(before.outward, 0);

    FaceOrientation counted;
    const int64_t restored = restoreNonInwardFaces(mesh, extracted, *grid, &counted);
    EXPECT_GE(restored, 1);
    EXPECT_EQ(mesh.point(pushed), extracted[17]);
    EXPECT_NE(mesh.point(other), extracted[100]);  // untouched: only faces that failed are restored
    const FaceOrientation after = checkFaceOrientation(mesh, *grid);
    EXPECT_EQ(after.outward, 0);
    EXPECT_EQ(after.inward, int64_t(mesh.n_faces()));
    // The guard's own counts (its first pass, updated for the faces it checked again) are
    // those of a fresh pass over the mesh it leaves (they are handed to the final checks).
    EXPECT_EQ(orientationCounts(counted), orientationCounts(after)) << "expected a fresh pass's counts";
    // Nothing left to restore: a second call is a no-op, and counts the same.
    FaceOrientation again;
    EXPECT_EQ(restoreNonInwardFaces(mesh, extracted, *grid, &again), 0);
    EXPECT_EQ(orientationCounts(again), orientationCounts(after));
}

TEST(LumenSurface, RejectsBadParameters)
{
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(5.f, openvdb::Vec3f(0.f), 0.5f, 3.f);
    const auto rejects = [&](const MeshParams& p, const std::string& field) {
        try {
            makeLumenSurface(*grid, p);
            ADD_FAILURE() << field << ": accepted";
        } catch (const ParameterError& e) {
            EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
        }
    };
    MeshParams p;
    p.smoothMethod = "laplace";
    rejects(p, "smoothMethod");
    p = MeshParams{};
    p.smoothIterations = -1;
    rejects(p, "smoothIterations");
    p = MeshParams{};
    p.smoothPassBand = 0.0;
    rejects(p, "smoothPassBand");
    p = MeshParams{};
    p.decimateFraction = 0.0;
    rejects(p, "decimateFraction");
    p = MeshParams{};
    p.decimateTargetFaces = -5;
    rejects(p, "decimateTargetFaces");
    p = MeshParams{};
    p.decimateMaxErrorVoxels = std::numeric_limits<double>::infinity();
    rejects(p, "decimateMaxErrorVoxels");
    p = MeshParams{};
    p.decimateMaxNormalDeviationDeg = 270.0;
    rejects(p, "decimateMaxNormalDeviationDeg");
    p = MeshParams{};
    p.adaptivity = -0.1;
    rejects(p, "adaptivity");
    EXPECT_NO_THROW(validateMeshParams(MeshParams{}));
}

} // namespace
} // namespace flyover
