// The fly-over elevation from the framed half-width R(p) (render/flyover_path.h): a wall that
// bulges beyond the inscribed radius D(p) near the cutting line is framed by R and missed by
// h = D (the failure that left 1.5% of the full phantom unseen), R is smooth along the path.
#include "render/coverage.h"
#include "render/flyover_path.h"

#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cmath>

namespace flyover {
namespace {


/// An elliptic lumen along z (0..100 mm): semi-axis 10 mm along x and `lateral` mm along y.
TriMesh ellipticTube(double lateral)
{
    std::vector<double> z, r;
    for (double v = 0; v <= 100.0 + 1e-9; v += 1.0) {
        z.push_back(v);
        r.push_back(10.0);
    }
    TriMesh mesh = test::makeLathe(z, r, 128, /*inward=*/true);
    for (const auto v : mesh.vertices()) {
        TriMesh::Point p = mesh.point(v);
        p[1] *= float(lateral / 10.0);
        mesh.set_point(v, p);
    }
    return mesh;
}

/// The axis from z = 10 to 90, D = 10, normal +x: the cameras look along x, so y (the long
/// semi-axis) is the image's vertical axis, where the two views meet.
Centerline axisCenterline()
{
    Centerline c;
    c.stepMm = 1.0;
    for (int k = 10; k <= 90; ++k) {
        CenterlinePoint p;
        p.positionMm = {0, 0, double(k)};
        p.tangent = {0, 0, 1};
        p.normal = {1, 0, 0};
        p.radiusMm = 10.0;
        c.points.push_back(p);
    }
    return c;
}

/// True when `x` projects inside the camera's image, beyond its near plane.
bool inFrustum(const Camera& c, const Vec3d& x)
{
    const Vec3d v = x - c.position;
    const double depth = dot(v, c.forward);
    if (!(depth > c.nearMm)) return false;
    const double tanHalf = std::tan(0.5 * c.fovDeg * PI / 180.0);
    return std::fabs(dot(v, c.right) / depth) <= tanHalf && std::fabs(dot(v, c.up) / depth) <= tanHalf;
}

TEST(FlyoverFrameRadii, FrameTheLongAxisOfAnEllipticLumen)
{
    const RayScene scene(ellipticTube(16.0));
    const Centerline cl = axisCenterline();
    const FlyoverParams fp;
    const std::vector<double> R = flyoverFrameRadii(scene, cl, fp);
    ASSERT_EQ(R.size(), cl.points.size());
    SCOPED_TRACE("elliptic tube, semi-axes 10 (view axis) and 16 (lateral) mm, fov 90, margin 5%");
    for (std::size_t i = 0; i < R.size(); ++i) {
        // max over the wall of lateral - depth * tan(45) is the long semi-axis, 16 mm; +5%.
        EXPECT_NEAR(R[i], 16.0 * 1.05, 0.25) << "point " << i;
        EXPECT_GE(R[i], cl.points[i].radiusMm);
    }
}

TEST(FlyoverFrameRadii, WallPointsWhereTheViewsMeetAreFramedOnlyWithR)
{
    const TriMesh mesh = ellipticTube(16.0);
    const RayScene scene(mesh);
    const Centerline cl = axisCenterline();
    const FlyoverParams fp;
    const std::vector<double> R = flyoverFrameRadii(scene, cl, fp);
    int framedWithR = 0, framedWithD = 0, checked = 0;
    for (const auto v : mesh.vertices()) {
        const Vec3d x = test::toVec(mesh.point(v));
        if (x.z < 20 || x.z > 80 || std::fabs(x.y) < 15.0) continue;  // the lateral extremes only
        const std::size_t i = std::size_t(std::lround(x.z)) - 10;
        // With OST each camera shows the wall beyond the centerline plane: camera 0 looks
        // along -n = -x and shows x <= 0, camera 1 the rest.
        auto framed = [&](double frame) {
            const auto cams = flyoverCameras(cl.points[i], fp, frame);
            return (x.x <= 0 && inFrustum(cams[0], x)) || (x.x >= 0 && inFrustum(cams[1], x));
        };
        framedWithR += framed(R[i]) ? 1 : 0;
        framedWithD += framed(-1.0) ? 1 : 0;
        ++checked;
    }
    ASSERT_GT(checked, 100);
    EXPECT_EQ(framedWithR, checked) << "every wall point with |y| >= 15 mm framed by its own pair at h = R";
    EXPECT_EQ(framedWithD, 0) << "at h = D = 10 mm the views end at |y| = 10 mm";
}

TEST(FlyoverFrameRadii, CoverageOfAnEllipticLumen)
{
    const RayScene scene(ellipticTube(16.0));
    Centerline cl = axisCenterline();
    CoverageParams p;
    p.viewPx = 64;
    p.stepMm = 2.0;
    p.flythrough = false;
    const CoverageResult c = computeCoverage(scene, cl, p);
    // The tube runs 10 mm past the centerline's ends; its middle must be seen whole.
    SCOPED_TRACE("elliptic tube 10 x 16 mm, 64 px every 2 mm");
    EXPECT_GE(c.flyover.fraction, 0.9);
    double missedInMiddle = 0;
    for (const MissedRegion& r : c.flyover.missed)
        if (r.centroidMm.z > 25 && r.centroidMm.z < 75) missedInMiddle += r.areaMm2;
    EXPECT_EQ(missedInMiddle, 0.0);

    // The radii a caller already has give the same result; a wrong count is refused.
    p.frameRadiiMm = flyoverFrameRadii(scene, cl, p.flyover);
    EXPECT_EQ(computeCoverage(scene, cl, p).flyover.seen, c.flyover.seen);
    p.frameRadiiMm.pop_back();
    EXPECT_THROW(computeCoverage(scene, cl, p), ParameterError);
}

TEST(FlyoverFrameRadii, SmoothAlongThePathAndNeverBelowWhatAPointNeeds)
{
    // A lumen that widens from radius 10 to 16 over 2 mm at z = 50: R must rise ahead of the
    // step (the running maximum) and change by little per millimetre (no jumping camera).
    std::vector<double> z, r;
    for (double v = 0; v <= 100.0 + 1e-9; v += 0.5) {
        z.push_back(v);
        r.push_back(v < 49 ? 10.0 : v > 51 ? 16.0 : 10.0 + 3.0 * (v - 49));
    }
    const RayScene scene(test::makeLathe(z, r, 128, true));
    Centerline cl = axisCenterline();
    for (auto& p : cl.points) p.radiusMm = p.positionMm.z < 50 ? 10.0 : 16.0;
    const std::vector<double> R = flyoverFrameRadii(scene, cl, FlyoverParams{});
    double maxStep = 0;
    for (std::size_t i = 0; i < R.size(); ++i) {
        const double zi = cl.points[i].positionMm.z;
        const double need = zi < 49 ? 10.0 : zi > 51 ? 16.0 : 10.0 + 3.0 * (zi - 49);
        EXPECT_GE(R[i], need) << "z " << zi;
        if (i > 0) maxStep = std::max(maxStep, std::fabs(R[i] - R[i - 1]));
    }
    EXPECT_LT(maxStep, 1.0) << "largest change of R between 1 mm steps (mm)";
}

// One point's R from the points within its reach only (as the first pair takes it): the same
// double as the whole function's, with and without the Gaussian, at every point.
TEST(FlyoverFrameRadii, OnePointsRadiusIsTheSameDoubleAsTheWholeFunctions)
{
    // A lumen whose lateral semi-axis grows along z, so that R varies from point to point.
    TriMesh mesh = ellipticTube(10.0);
    for (const auto v : mesh.vertices()) {
        TriMesh::Point p = mesh.point(v);
        p[1] *= float(1.0 + 0.01 * p[2]);
        mesh.set_point(v, p);
    }
    const RayScene scene(mesh);
    const Centerline cl = axisCenterline();
    FlyoverParams fp;
    for (const double smoothMm : {4.0, 0.0}) {
        FrameRadiusOptions o;
        o.smoothMm = smoothMm;
        const std::vector<double> R = flyoverFrameRadii(scene, cl, fp, o);
        for (std::size_t i = 0; i < cl.points.size(); ++i)
            EXPECT_EQ(flyoverFrameRadiusAt(scene, cl, fp, i, o), R[i]) << "index " << i << ", smoothing " << smoothMm;
        const auto [first, last] = frameRadiusReach(cl, 0, o);
        EXPECT_EQ(first, 0u);
        EXPECT_EQ(last, smoothMm > 0 ? 8u + 12u : 8u) << "the window (8 mm) plus 3 sigma of the Gaussian, 1 mm steps";
    }
    EXPECT_GT(flyoverFrameRadii(scene, cl, fp).back(), flyoverFrameRadii(scene, cl, fp).front() + 1.0)
        << "R should grow with the lumen";
}

TEST(FlyoverFrameRadii, RejectsBadParameters)
{
    const RayScene scene(ellipticTube(12.0));
    const Centerline cl = axisCenterline();
    FlyoverParams fp;
    fp.fovDeg = 180;
    EXPECT_THROW(flyoverFrameRadii(scene, cl, fp), ParameterError);
    FrameRadiusOptions o;
    o.fanRays = 2;
    EXPECT_THROW(flyoverFrameRadii(scene, cl, FlyoverParams{}, o), ParameterError);
    EXPECT_THROW(flyoverCameras(cl.points[0], FlyoverParams{}, std::nan("")), InputError);
}

} // namespace
} // namespace flyover
