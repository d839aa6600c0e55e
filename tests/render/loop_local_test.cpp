// Loop-local OST: a hairpin whose two limbs press together (a wide limb A beside a narrow limb
// B, 2 mm of gap between their walls, 270 mm apart along the path). The part of A's wall that
// faces B lies nearer to B's axis than to A's own, so the nearest path point in space is the
// wrong owner; through the lumen the owner is A. A fly-over view on A shows B's wall in its
// margins under the thesis' OST, and none of it loop-local.
#include "render/camera.h"
#include "render/flyover_path.h"
#include "render/loop_ownership.h"
#include "render/coverage.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

using namespace flyover;

namespace {

constexpr double RADIUS_A = 14.0, RADIUS_B = 6.0, AXIS_GAP = 22.0, LIMB = 200.0;

struct Hairpin {
    std::vector<Vec3d> path;
    std::vector<double> radius;
    std::vector<double> arc;
    std::size_t firstOfB = 0;  ///< path index where limb B (going down) starts
    TriMesh mesh;
    Centerline centerline;
    uint32_t firstTriangleOfB = 0;  ///< faces of B's ring segments start here
};

/// A up the z axis (radius 14, narrowing to 6 over z 150..180), a half turn of radius 11 at
/// the top, B down at x = 22 (radius 6): 0.5 mm samples.
Hairpin hairpin()
{
    Hairpin h;
    const double step = 0.5;
    for (double z = 0; z < LIMB; z += step) {
        h.path.push_back({0, 0, z});
        const double f = std::clamp((z - 150.0) / 30.0, 0.0, 1.0);
        h.radius.push_back(RADIUS_A + (RADIUS_B - RADIUS_A) * f);
    }
    const double rb = 0.5 * AXIS_GAP;
    const int turn = int(std::ceil(PI * rb / step));
    for (int k = 0; k < turn; ++k) {
        const double a = PI * double(k) / double(turn);
        h.path.push_back({rb - rb * std::cos(a), 0, LIMB + rb * std::sin(a)});
        h.radius.push_back(RADIUS_B);
    }
    h.firstOfB = h.path.size();
    for (double z = LIMB; z >= 0; z -= step) {
        h.path.push_back({AXIS_GAP, 0, z});
        h.radius.push_back(RADIUS_B);
    }
    constexpr int SEGMENTS = 96;
    h.mesh = test::makeSweptTube(h.path, h.radius, SEGMENTS, /*inward=*/true);
    h.firstTriangleOfB = uint32_t(2 * SEGMENTS * h.firstOfB);
    // The centerline: 1 mm steps along the same path.
    h.arc.assign(h.path.size(), 0.0);
    for (std::size_t i = 1; i < h.path.size(); ++i) h.arc[i] = h.arc[i - 1] + distance(h.path[i - 1], h.path[i]);
    h.centerline.stepMm = 1.0;
    std::size_t j = 0;
    for (double s = 0; s <= h.arc.back(); s += 1.0) {
        while (j + 1 < h.path.size() && h.arc[j + 1] < s) ++j;
        const double t = h.arc[j + 1] > h.arc[j] ? (s - h.arc[j]) / (h.arc[j + 1] - h.arc[j]) : 0.0;
        CenterlinePoint p;
        p.positionMm = h.path[j] + (h.path[j + 1] - h.path[j]) * t;
        p.radiusMm = h.radius[j];
        h.centerline.points.push_back(p);
    }
    computeTangentsAndNormals(h.centerline);
    return h;
}

Vec3d centroidOf(const RayScene& scene, uint32_t f)
{
    const auto t = scene.triangle(f);
    return (scene.vertex(t[0]) + scene.vertex(t[1]) + scene.vertex(t[2])) / 3.0;
}

/// Arc (mm) of B's axis at height z.
double arcOfB(const Hairpin& h, double z) { return h.arc[h.firstOfB] + (LIMB - z); }

} // namespace

TEST(LoopOwnership, AWallFacingTheNextLoopBelongsToItsOwnLoopNotTheNearestPathPoint)
{
    const Hairpin h = hairpin();
    const RayScene scene(h.mesh);
    const TriangleOwners owners = triangleOwners(scene, h.centerline);
    ASSERT_EQ(owners.arcMm.size(), scene.triangleCount());
    EXPECT_EQ(owners.bySight + owners.byNeighbour + owners.unowned, std::size_t(scene.triangleCount()));
    EXPECT_EQ(owners.unowned, 0u) << "every triangle of an open tube is seen from its own axis";
    std::size_t facing = 0, wrongFacing = 0, nearestWouldBeWrong = 0, ofB = 0, wrongB = 0;
    for (uint32_t f = 0; f < scene.triangleCount(); ++f) {
        const Vec3d c = centroidOf(scene, f);
        if (c.z < 40 || c.z > 120) continue;
        const double owner = owners.arcMm[f];
        if (f < h.firstTriangleOfB) {
            if (c.x < 8.0) continue;  // A's wall facing B
            ++facing;
            if (distance(c, Vec3d{AXIS_GAP, 0, c.z}) < distance(c, Vec3d{0, 0, c.z})) ++nearestWouldBeWrong;
            if (!(std::fabs(owner - c.z) < 25.0)) ++wrongFacing;
        } else {
            ++ofB;
            if (!(std::fabs(owner - arcOfB(h, c.z)) < 25.0)) ++wrongB;
        }
    }
    ASSERT_GT(facing, 100u);
    EXPECT_GT(nearestWouldBeWrong, facing / 2) << "the test's geometry no longer fools the nearest point";
    EXPECT_EQ(wrongFacing, 0u) << "of " << facing << " triangles of A facing B, " << wrongFacing
                               << " were given an owner more than 25 mm from their own place on A";
    EXPECT_EQ(wrongB, 0u) << "of " << ofB << " triangles of B, " << wrongB << " were given a wrong owner";
}

TEST(LoopOwnership, AFoldsHiddenSideTakesItsNeighboursOwner)
{
    // An annular fold: its far flank is seen from the axis beyond it, its tip from both sides;
    // nothing stays unowned and every owner lies within reach of the fold.
    const test::FoldedTube tube{10.0, 120.0, 60.0, 7.0, 2.0};
    const RayScene scene(tube.mesh());
    const Centerline cl = tube.centerline();
    const TriangleOwners owners = triangleOwners(scene, cl);
    EXPECT_EQ(owners.unowned, 0u);
    for (uint32_t f = 0; f < scene.triangleCount(); ++f) {
        const Vec3d c = centroidOf(scene, f);
        if (c.z < 20 || c.z > 100) continue;
        const double ownerZ = owners.arcMm[f] + 10.0;  // the centerline starts at z = 10
        ASSERT_LT(std::fabs(ownerZ - c.z), 40.0) << "triangle " << f << " at z " << c.z << " owned from z " << ownerZ;
    }
}

TEST(LoopLocalOst, AViewOnOneLimbShowsNoneOfTheLimbPressedAgainstIt)
{
    const Hairpin h = hairpin();
    const RayScene scene(h.mesh);
    const std::vector<float> owners = triangleOwners(scene, h.centerline).arcMm;
    // On A at z = 80, the pair rolled so that B lies across the views (both cameras look
    // perpendicular to the direction from A to B).
    const CenterlinePoint& p = h.centerline.points[80];
    FlyoverParams fp;
    fp.rollDeg = cuttingLineRollDeg(p, Vec3d{1, 0, 0});
    const auto cams = flyoverCameras(p, fp, 20.0);
    RenderOptions ro;
    ro.widthPx = ro.heightPx = 128;
    std::size_t thesisB = 0, localB = 0, foreignThesis = 0;
    LoopCounts counts;
    for (const Camera& cam : cams) {
        HitImage thesis, local;
        traceHits(scene, cam, ro, thesis);
        RenderOptions lo = ro;
        lo.loop = LoopWindow{&owners, 80.0, 80.0};
        traceHits(scene, cam, lo, local, &counts);
        for (std::size_t i = 0; i < thesis.primId.size(); ++i) {
            if (thesis.t[i] >= 0 && thesis.primId[i] >= h.firstTriangleOfB) ++thesisB;
            if (thesis.t[i] >= 0 && std::fabs(owners[thesis.primId[i]] - 80.0) > 80.0) ++foreignThesis;
            if (local.t[i] >= 0 && local.primId[i] >= h.firstTriangleOfB) ++localB;
        }
        // The rendered image agrees with the hit image: the same rays, the same window.
        RgbImage image;
        HitImage rendered;
        renderView(scene, cam, lo, image, &rendered);
        EXPECT_EQ(rendered.primId, local.primId);
    }
    ASSERT_GT(thesisB, 200u) << "the thesis' OST should show B in the views' margins";
    EXPECT_EQ(localB, 0u) << "loop-local OST still showed " << localB << " pixels of B";
    EXPECT_EQ(counts.passedPixels, foreignThesis) << "the counts should name every pixel whose wall was B's";
    EXPECT_GT(counts.passedShare(), 0.02);
    EXPECT_LT(counts.passedShare(), 0.6);
    // The same rule for one ray (the viewer's pick).
    const Camera& cam = cams[0];
    int picked = 0, pickedB = 0;
    for (int y = 4; y < 128; y += 8)
        for (int x = 4; x < 128; x += 8) {
            const Vec3d dir = pixelDirection(cam, 128, 128, x + 0.5, y + 0.5);
            const RayHit hit = scene.intersect(cam.position, dir, cam.nearMm, 1e30, true, LoopWindow{&owners, 80.0, 80.0});
            picked += hit.hit ? 1 : 0;
            pickedB += (hit.hit && hit.primId >= h.firstTriangleOfB) ? 1 : 0;
        }
    EXPECT_GT(picked, 50);
    EXPECT_EQ(pickedB, 0);
}

TEST(LoopLocalOst, AWindowOfTheWrongSizeIsRefused)
{
    const Hairpin h = hairpin();
    const RayScene scene(h.mesh);
    const std::vector<float> owners(10, 0.0f);
    RenderOptions ro;
    ro.widthPx = ro.heightPx = 16;
    ro.loop = LoopWindow{&owners, 0.0, 80.0};
    const auto cams = flyoverCameras(h.centerline.points[80], FlyoverParams{}, 20.0);
    HitImage hits;
    EXPECT_THROW(traceHits(scene, cams[0], ro, hits), ParameterError);
    EXPECT_THROW(scene.intersect(cams[0].position, cams[0].forward, 0, 1e30, true, ro.loop), ParameterError);
}

TEST(LoopLocalOst, CoverageCountsOnlyWhatAViewShowsOfItsOwnLoop)
{
    // Coverage from A's stretch only (a centerline over A): thesis OST marks some of B's wall
    // seen from A's views; loop-local marks none of it.
    const Hairpin h = hairpin();
    const RayScene scene(h.mesh);
    const std::vector<float> owners = triangleOwners(scene, h.centerline).arcMm;
    CoverageParams cp;
    cp.viewPx = 64;
    cp.stepMm = 4.0;
    cp.flythrough = false;
    cp.footprint = false;
    cp.flyover.rollDeg = cuttingLineRollDeg(h.centerline.points[80], Vec3d{1, 0, 0});
    Centerline a = h.centerline;
    a.points.assign(h.centerline.points.begin() + 40, h.centerline.points.begin() + 121);
    cp.frameRadiiMm.assign(a.points.size(), 20.0);  // as the views of the test above
    // Owners are arcs of the whole path; a's index 0 is the whole path's 40.
    std::vector<float> shifted(owners);
    for (float& o : shifted) o -= 40.0f;
    const CoverageResult thesis = computeCoverage(scene, a, cp);
    cp.ownerArcMm = &shifted;
    cp.loopReachMm = 80.0;
    const CoverageResult local = computeCoverage(scene, a, cp);
    std::size_t thesisB = 0, localB = 0;
    for (uint32_t f = h.firstTriangleOfB; f < scene.triangleCount(); ++f) {
        thesisB += thesis.flyover.seen[f];
        localB += local.flyover.seen[f];
    }
    EXPECT_GT(thesisB, 20u);
    EXPECT_EQ(localB, 0u);
}
