#include "render/coverage.h"

#include "reference_marker.h"
#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace flyover {
namespace {

using test::FoldedTube;

/// The folded tube's mesh, its ray scene and its centerline.
struct FoldedTubeScene {
    FoldedTube tube;
    TriMesh mesh = tube.mesh();
    RayScene scene{mesh};
    Centerline line = tube.centerline();
};
using test::circleCenterline;

TEST(CenterlineLocator, AgreesWithBruteForce)
{
    Centerline line;
    line.stepMm = 1.0;
    for (int i = 0; i < 800; ++i) {
        const double s = i / 25.0;
        CenterlinePoint p;
        p.positionMm = {25.0 * std::cos(s), 25.0 * std::sin(s), 3.0 * s};
        line.points.push_back(p);
    }
    const CenterlineLocator locator(line, 8.0);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-80.0, 180.0);
    for (int k = 0; k < 3000; ++k) {
        const Vec3d q{u(rng) * 0.5, u(rng) * 0.5, u(rng)};
        double best = std::numeric_limits<double>::infinity();
        for (const auto& p : line.points) best = std::min(best, distance(q, p.positionMm));
        const std::size_t i = locator.nearest(q);
        ASSERT_LT(i, line.points.size());
        EXPECT_NEAR(distance(q, line.points[i].positionMm), best, 1e-9) << "seed 11 query " << k;
    }
    EXPECT_THROW(CenterlineLocator(Centerline{}), InputError);
}

TEST(TriangleGeometry, AreasSumToTheLatheArea)
{
    // A cylinder of radius 10 and length 50 (as a 256-gon): lateral area 2 * n * sin(pi/n) * r * L.
    const int n = 256;
    const TriMesh mesh = test::makeLathe({0.0, 25.0, 50.0}, {10.0, 10.0, 10.0}, n, true);
    const RayScene scene(mesh);
    const TriangleGeometry g = triangleGeometry(scene);
    double area = 0;
    for (const double a : g.areaMm2) area += a;
    EXPECT_NEAR(area, 2.0 * n * std::sin(PI / n) * 10.0 * 50.0, 1e-6 * area);
}

TEST(Coverage, FlyoverSeesAllOfATorusLumen)
{
    const double R = 60.0, r = 10.0;
    const TriMesh mesh = test::makeTorus({0, 0, 0}, R, r, 256, 64, /*inward=*/true);
    const RayScene scene(mesh);
    const Centerline line = circleCenterline(R, r);
    CoverageParams p;
    p.viewPx = 64;
    p.stepMm = 2.0;
    const CoverageResult c = computeCoverage(scene, line, p);
    RecordProperty("flyover", std::to_string(c.flyover.fraction));
    RecordProperty("flythroughTwoWay", std::to_string(c.flythroughTwoWay.fraction));
    SCOPED_TRACE("torus R=60 r=10, 64 px every 2 mm");
    EXPECT_NEAR(c.totalAreaMm2, 4.0 * PI * PI * R * r, 0.01 * c.totalAreaMm2);
    EXPECT_GE(c.flyover.fraction, 0.999);
    EXPECT_TRUE(c.flyover.missed.empty());
    // Every second point, and the last one.
    const std::size_t n = line.points.size();
    EXPECT_EQ(c.positions, (n + 1) / 2 + ((n - 1) % 2 != 0 ? 1 : 0));
    EXPECT_EQ(c.rays, uint64_t(c.positions) * 4u * 64u * 64u);
    // Two-way fly-through is the union of its directions.
    EXPECT_GE(c.flythroughTwoWay.fraction, std::max(c.flythroughForward.fraction, c.flythroughBackward.fraction));
    EXPECT_LE(c.flythroughTwoWay.fraction, c.flythroughForward.fraction + c.flythroughBackward.fraction);
}

TEST(Coverage, FoldHidesTheWallBehindItFromTheForwardFlythroughOnly)
{
    const FoldedTubeScene folded;
    const RayScene& scene = folded.scene;
    const Centerline& line = folded.line;
    CoverageParams p;
    p.viewPx = 96;
    p.stepMm = 1.0;
    p.minRegionMm2 = 10.0;
    const CoverageResult c = computeCoverage(scene, line, p);
    SCOPED_TRACE("tube r=10 with a fold of depth 5 at z=60");
    RecordProperty("flyover", std::to_string(c.flyover.fraction));
    RecordProperty("forward", std::to_string(c.flythroughForward.fraction));
    RecordProperty("twoWay", std::to_string(c.flythroughTwoWay.fraction));

    // Only the tube's ends (beyond the centerline's ends, 10 mm in, seen obliquely) may escape
    // the fly-over; the forward fly-through misses the fold's far flank and the wall in its
    // shadow, which the backward pass sees.
    EXPECT_GE(c.flyover.fraction, c.flythroughTwoWay.fraction);
    EXPECT_GT(c.flythroughTwoWay.fraction, c.flythroughForward.fraction + 0.01);
    ASSERT_FALSE(c.flythroughForward.missed.empty());
    bool behindFold = false;
    for (const MissedRegion& m : c.flythroughForward.missed) {
        EXPECT_GE(m.areaMm2, p.minRegionMm2);
        EXPECT_LT(m.nearestCenterlineIndex, line.points.size());
        EXPECT_NEAR(m.arcMm, double(m.nearestCenterlineIndex) * line.stepMm, 1e-9);
        EXPECT_NEAR(m.distanceToCenterlineMm, distance(m.centroidMm, line.points[m.nearestCenterlineIndex].positionMm), 1e-9);
        // A ring region has its centroid on the axis; what matters is where along it lies.
        behindFold = behindFold || (m.centroidMm.z > folded.tube.zFold && m.centroidMm.z < folded.tube.zFold + 15.0);
    }
    EXPECT_TRUE(behindFold) << "the largest forward miss is at z = " << c.flythroughForward.missed.front().centroidMm.z;
    double listed = 0;
    for (const MissedRegion& m : c.flythroughForward.missed) listed += m.areaMm2;
    EXPECT_NEAR(listed, c.flythroughForward.missedInListedRegionsMm2, 1e-6 * c.totalAreaMm2);
    EXPECT_LE(listed, (1.0 - c.flythroughForward.fraction) * c.totalAreaMm2 + 1e-6 * c.totalAreaMm2);
    // Sorted largest first.
    for (std::size_t k = 1; k < c.flythroughForward.missed.size(); ++k)
        EXPECT_GE(c.flythroughForward.missed[k - 1].areaMm2, c.flythroughForward.missed[k].areaMm2);
}

TEST(Coverage, FootprintConvergesFasterThanHitTrianglesAlone)
{
    // Counting only the triangles rays hit is pessimistic at low resolution; the footprint rule
    // is closer at low resolution to what both give at high resolution.
    const FoldedTube tube;
    const TriMesh mesh = tube.mesh(0.2, 192);
    const RayScene scene(mesh);
    const Centerline line = tube.centerline();
    auto fraction = [&](int px, bool footprint) {
        CoverageParams p;
        p.viewPx = px;
        p.stepMm = 4.0;
        p.footprint = footprint;
        p.flythrough = true;
        return computeCoverage(scene, line, p).flythroughForward.fraction;
    };
    const double fine = fraction(256, false);
    const double coarseHit = fraction(32, false), coarseFootprint = fraction(32, true);
    RecordProperty("fine", std::to_string(fine));
    RecordProperty("coarseHit", std::to_string(coarseHit));
    RecordProperty("coarseFootprint", std::to_string(coarseFootprint));
    EXPECT_LT(std::fabs(coarseFootprint - fine), std::fabs(coarseHit - fine));
    EXPECT_LT(coarseHit, fine);
}

/// The folded tube's fine mesh (long footprint walks, grazing views at the fold) as the arrays
/// RayScene takes, for the footprint-walk tests to extend; triangles from `meshTriangles` on
/// are the ones a test added.
struct FineTubeArrays {
    FoldedTube tube;
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    uint32_t meshTriangles = 0;

    FineTubeArrays()
    {
        const TriMesh mesh = tube.mesh(0.2, 192);
        for (const auto v : mesh.vertices())
            for (int k = 0; k < 3; ++k) xyz.push_back(mesh.point(v)[k]);
        for (const auto f : mesh.faces())
            for (const auto v : mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
        meshTriangles = uint32_t(tris.size() / 3);
    }
};

/// ViewMarker (viewPx rays a side, footprint on) against the plain rule (reference_marker.h:
/// scanning the triangles around each vertex) at every `every`-th point of `line`: both
/// fly-over cameras and the forward fly-through, OST on and off. Returns the views compared;
/// `reachingExtra` counts those whose plain-rule triangles include one of index >= firstExtra
/// (the triangles a test added to the tube).
std::size_t expectWalkMatchesPlainRule(const RayScene& scene, const Centerline& line, int viewPx, std::size_t every,
                                       uint32_t firstExtra, std::size_t& reachingExtra)
{
    const FlyoverParams fp;
    ViewMarker marker(scene, viewPx, true);
    const auto around = test::trianglesAroundVertices(scene);
    std::size_t views = 0;
    reachingExtra = 0;
    for (std::size_t i = 0; i < line.points.size(); i += every) {
        std::vector<Camera> cams;
        for (const Camera& c : flyoverCameras(line.points[i], fp, 1.2 * line.points[i].radiusMm)) cams.push_back(c);
        cams.push_back(flythroughCamera(line.points[i], true, 90.0));
        for (std::size_t c = 0; c < cams.size(); ++c)
            for (const bool ost : {true, false}) {
                std::vector<uint32_t> got;
                marker.mark(cams[c], ost, got);
                std::sort(got.begin(), got.end());
                got.erase(std::unique(got.begin(), got.end()), got.end());
                const auto want = test::referenceMark(scene, around, cams[c], viewPx, ost, true);
                EXPECT_EQ(got, want) << "centerline point " << i << ", camera " << c << ", ost " << ost << ": "
                                     << got.size() << " triangles marked, the plain rule marks " << want.size();
                reachingExtra += std::any_of(want.begin(), want.end(), [&](uint32_t f) { return f >= firstExtra; });
                ++views;
            }
    }
    return views;
}

TEST(Coverage, FootprintWalkMatchesThePlainRuleOnAFineMesh)
{
    // A fine mesh and a non-manifold piece: ViewMarker's rows of edge neighbours must give what
    // scanning the triangles around each vertex gives, with and without OST.
    FineTubeArrays t;
    auto& xyz = t.xyz;
    auto& tris = t.tris;
    const uint32_t meshTriangles = t.meshTriangles;
    {
        // Two extra triangles on the first triangle's first edge make it non-manifold.
        const uint32_t a = tris[0], b = tris[1];
        for (const float side : {1.0f, -1.0f}) {
            const uint32_t c = uint32_t(xyz.size() / 3);
            for (int k = 0; k < 3; ++k) xyz.push_back(0.5f * (xyz[3 * a + k] + xyz[3 * b + k]) + side * 0.3f);
            tris.insert(tris.end(), {side > 0 ? b : a, side > 0 ? a : b, c});
        }
    }
    const RayScene scene(std::move(xyz), std::move(tris));
    std::size_t reachingExtra = 0;
    EXPECT_GE(expectWalkMatchesPlainRule(scene, t.tube.centerline(), 64, 10, meshTriangles, reachingExtra), 30u);
}

TEST(Coverage, FootprintWalkMatchesThePlainRuleWithRepeatedCorners)
{
    // A triangle with a repeated corner, (a, a, b) on an edge (a, b) of the mesh, has every
    // triangle around a as an edge neighbour (they hold both ends of its edge (a, a)), and
    // those share one corner with it, not two: a walk that tested only a neighbour's corner
    // off the shared edge would miss their third corner. Without OST such a triangle passes
    // the facing test, so the walk goes through it.
    FineTubeArrays t;
    auto& xyz = t.xyz;
    auto& tris = t.tris;
    const uint32_t meshTriangles = t.meshTriangles;
    for (std::size_t f = 0; f < meshTriangles; f += 7) tris.insert(tris.end(), {tris[3 * f], tris[3 * f], tris[3 * f + 1]});
    const RayScene scene(std::move(xyz), std::move(tris));
    std::size_t withRepeated = 0;
    EXPECT_GE(expectWalkMatchesPlainRule(scene, t.tube.centerline(), 48, 8, meshTriangles, withRepeated), 60u);
    EXPECT_GT(withRepeated, 10u) << "the walk should pass through the triangles with a repeated corner";
}

TEST(Coverage, FootprintWalkMatchesThePlainRuleAtWideNonManifoldEdges)
{
    // Edges held by a dozen triangles (non-manifold fins): rows of more than eight edge
    // neighbours, each reached from several triangles; the walk must mark each once and
    // miss none.
    FineTubeArrays t;
    auto& xyz = t.xyz;
    auto& tris = t.tris;
    const uint32_t meshTriangles = t.meshTriangles;
    for (std::size_t f = 0; f < meshTriangles; f += 97) {
        const uint32_t a = tris[3 * f], b = tris[3 * f + 1], c = tris[3 * f + 2];
        for (int i = 1; i <= 10; ++i) {
            // Fins around the edge (a, b), between it and the third corner, pointing both ways.
            const uint32_t d = uint32_t(xyz.size() / 3);
            const float s = 0.08f * float(i), lift = (i % 2 ? 0.05f : -0.05f) * float(i);
            for (int k = 0; k < 3; ++k)
                xyz.push_back(0.5f * (xyz[3 * a + k] + xyz[3 * b + k]) + s * (xyz[3 * c + k] - xyz[3 * a + k]) + lift);
            tris.insert(tris.end(), {i % 2 ? a : b, i % 2 ? b : a, d});
        }
    }
    const RayScene scene(std::move(xyz), std::move(tris));
    std::size_t withFins = 0;
    EXPECT_GE(expectWalkMatchesPlainRule(scene, t.tube.centerline(), 48, 8, meshTriangles, withFins), 60u);
    EXPECT_GT(withFins, 10u) << "the walk should reach the fins";
}

TEST(Coverage, FlagsFromMarkAreTheTrianglesItLists)
{
    // computeCoverage has mark() flag the triangles in its per-method byte arrays; they must be
    // exactly those mark() lists (and those the plain rule marks), with and without the
    // footprint and OST, and flags already set must stay set.
    const FoldedTube tube;
    const TriMesh mesh = tube.mesh(0.2, 192);
    const RayScene scene(mesh);
    const Centerline line = tube.centerline();
    const auto around = test::trianglesAroundVertices(scene);
    FlyoverParams fp;
    std::size_t views = 0;
    for (const bool footprint : {true, false}) {
        ViewMarker marker(scene, 48, footprint);
        for (std::size_t i = 0; i < line.points.size(); i += 25) {
            std::vector<Camera> cams;
            for (const Camera& c : flyoverCameras(line.points[i], fp, 1.2 * line.points[i].radiusMm)) cams.push_back(c);
            cams.push_back(flythroughCamera(line.points[i], false, 90.0));
            for (const Camera& cam : cams)
                for (const bool ost : {true, false}) {
                    std::vector<uint32_t> listed;
                    const uint64_t raysListed = marker.mark(cam, ost, listed);
                    std::vector<uint8_t> flags(scene.triangleCount(), 0);
                    flags[0] = 1;  // set before: must stay set
                    const uint64_t raysFlagged = marker.mark(cam, ost, flags.data());
                    EXPECT_EQ(raysFlagged, raysListed);
                    std::vector<uint32_t> flagged;
                    for (uint32_t f = 0; f < flags.size(); ++f)
                        if (flags[f]) flagged.push_back(f);
                    listed.push_back(0);
                    std::sort(listed.begin(), listed.end());
                    listed.erase(std::unique(listed.begin(), listed.end()), listed.end());
                    EXPECT_EQ(flagged, listed) << "centerline point " << i << ", footprint " << footprint << ", ost "
                                               << ost << ": " << flagged.size() << " flagged, " << listed.size()
                                               << " listed";
                    auto want = test::referenceMark(scene, around, cam, 48, ost, footprint);
                    want.push_back(0);
                    std::sort(want.begin(), want.end());
                    want.erase(std::unique(want.begin(), want.end()), want.end());
                    EXPECT_EQ(flagged, want) << "centerline point " << i << ", footprint " << footprint << ", ost "
                                             << ost << ": the plain rule marks " << want.size();
                    EXPECT_GT(flagged.size(), 50u) << "the view should show many triangles";
                    ++views;
                }
        }
    }
    EXPECT_GE(views, 20u);
}

TEST(Coverage, RejectsBadParameters)
{
    const TriMesh mesh = test::makeTorus({0, 0, 0}, 60.0, 10.0, 32, 16, true);
    const RayScene scene(mesh);
    const Centerline line = circleCenterline(60.0, 10.0);
    CoverageParams p;
    p.viewPx = 4;
    EXPECT_THROW(computeCoverage(scene, line, p), ParameterError);
    p = CoverageParams{};
    p.stepMm = 0;
    EXPECT_THROW(computeCoverage(scene, line, p), ParameterError);
    EXPECT_THROW(computeCoverage(scene, Centerline{}, CoverageParams{}), InputError);
}

// A worker's marker (hit image, walk state) is the thread's own: while a thread waits for the
// tiles of its view's rays (a nested parallel loop), TBB may hand it another position, which
// must not take over that marker halfway (else frames and coverage differ between runs
// under load). Many threads on few cores make such steals frequent; every run must flag
// exactly the triangles one thread flags.
TEST(Coverage, SameFlagsOnAnyNumberOfThreadsUnderNestedStealing)
{
    const FoldedTubeScene folded;
    CoverageParams p;
    p.viewPx = 48;  // views every 1 mm, the default
    CoverageResult one;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = computeCoverage(folded.scene, folded.line, p);
    }
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 16);
    tbb::task_arena arena(16);
    for (int run = 0; run < 6; ++run) {
        CoverageResult many;
        arena.execute([&] { many = computeCoverage(folded.scene, folded.line, p); });
        EXPECT_TRUE(many.flyover.seen == one.flyover.seen) << "run " << run << ": fly-over flags differ from one thread's";
        EXPECT_TRUE(many.flythroughForward.seen == one.flythroughForward.seen)
            << "run " << run << ": forward fly-through flags differ from one thread's";
        EXPECT_TRUE(many.flythroughBackward.seen == one.flythroughBackward.seen)
            << "run " << run << ": backward fly-through flags differ from one thread's";
    }
}

} // namespace
} // namespace flyover
