#include "render/camera.h"
#include "volume/vec3.h"

#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace flyover {
namespace {

constexpr double EPS = 1e-9;  // double-precision frame arithmetic on mm-sized numbers

double degrees(double rad) { return rad * 180.0 / PI; }
double angleDeg(const Vec3d& a, const Vec3d& b)
{
    return degrees(std::atan2(length(cross(a, b)), dot(a, b)));
}

Vec3d randomUnit(std::mt19937& rng)
{
    std::normal_distribution<double> g(0.0, 1.0);
    for (;;) {
        const Vec3d v{g(rng), g(rng), g(rng)};
        if (length(v) > 1e-3) return normalize(v);
    }
}

/// Image-plane coordinates of a world point: x in [-1, 1] across the width (aspect 1), y up.
struct Projection {
    double x, y, depth;
};
Projection project(const Camera& c, const Vec3d& q)
{
    const Vec3d d = q - c.position;
    const double depth = dot(d, c.forward);
    const double tanHalf = std::tan(0.5 * c.fovDeg * PI / 180.0);
    return {dot(d, c.right) / (depth * tanHalf), dot(d, c.up) / (depth * tanHalf), depth};
}

void expectOrthonormalRightHanded(const Camera& c, const std::string& what)
{
    SCOPED_TRACE(what);
    EXPECT_NEAR(length(c.forward), 1.0, EPS);
    EXPECT_NEAR(length(c.up), 1.0, EPS);
    EXPECT_NEAR(length(c.right), 1.0, EPS);
    EXPECT_NEAR(dot(c.forward, c.up), 0.0, EPS);
    EXPECT_NEAR(dot(c.forward, c.right), 0.0, EPS);
    EXPECT_NEAR(dot(c.up, c.right), 0.0, EPS);
    // right = forward x up (camera.h).
    EXPECT_NEAR(distance(cross(c.forward, c.up), c.right), 0.0, EPS);
}

CenterlinePoint randomPoint(std::mt19937& rng)
{
    std::uniform_real_distribution<double> pos(-200.0, 200.0), rad(0.5, 30.0);
    CenterlinePoint p;
    p.positionMm = {pos(rng), pos(rng), pos(rng)};
    p.tangent = randomUnit(rng);
    const Vec3d other = randomUnit(rng);
    p.normal = normalize(other - p.tangent * dot(other, p.tangent));
    p.radiusMm = rad(rng);
    return p;
}

TEST(LookAt, FrameIsOrthonormalRightHandedAndLooksAtTarget)
{
    std::mt19937 rng(1234);
    for (int i = 0; i < 200; ++i) {
        const Vec3d pos = randomUnit(rng) * 50.0, target = randomUnit(rng) * 10.0;
        const Vec3d upHint = randomUnit(rng);
        const Camera c = lookAt(pos, target, upHint, 60.0);
        expectOrthonormalRightHanded(c, "lookAt seed 1234 #" + std::to_string(i));
        EXPECT_NEAR(distance(c.forward, normalize(target - pos)), 0.0, EPS);
        EXPECT_GT(dot(c.up, upHint), -EPS);  // up is the hint made perpendicular, not its opposite
    }
    // An up hint parallel to the view direction still gives a valid frame.
    expectOrthonormalRightHanded(lookAt({0, 0, 0}, {0, 0, 5}, {0, 0, 1}, 60.0), "parallel hint");
}

TEST(FlyoverCameras, FramesOrthonormalRightHandedLookingAtPointFromElevation)
{
    std::mt19937 rng(20240611);
    std::uniform_real_distribution<double> rollDist(-360.0, 360.0), fovDist(20.0, 120.0);
    for (int i = 0; i < 1000; ++i) {
        const CenterlinePoint p = randomPoint(rng);
        FlyoverParams params;
        params.rollDeg = rollDist(rng);
        params.fovDeg = fovDist(rng);
        params.leftToRight = (i % 2) == 0;
        const auto cams = flyoverCameras(p, params);
        const double h = p.radiusMm / std::tan(0.5 * params.fovDeg * PI / 180.0);
        for (int k = 0; k < 2; ++k) {
            const Camera& c = cams[std::size_t(k)];
            const std::string what = "seed 20240611 #" + std::to_string(i) + " camera " + std::to_string(k) +
                                     " roll " + std::to_string(params.rollDeg) + " fov " +
                                     std::to_string(params.fovDeg);
            expectOrthonormalRightHanded(c, what);
            SCOPED_TRACE(what);
            EXPECT_NEAR(distance(c.position, p.positionMm), h, 1e-9 * (1.0 + h));
            EXPECT_NEAR(distance(normalize(p.positionMm - c.position), c.forward), 0.0, 1e-9);
            EXPECT_NEAR(dot(c.forward, p.tangent), 0.0, EPS);  // camera perpendicular to the path
            EXPECT_NEAR(dot(c.up, p.tangent), 0.0, EPS);       // tangent runs horizontally
            EXPECT_EQ(c.fovDeg, params.fovDeg);
        }
        // Opposite sides of the point.
        EXPECT_NEAR(distance((cams[0].position + cams[1].position) * 0.5, p.positionMm), 0.0, 1e-9 * (1.0 + h));
    }
}

TEST(FlyoverCameras, ElevationEqualsRadiusAtNinetyDegrees)
{
    CenterlinePoint p;
    p.positionMm = {10, 20, 30};
    p.tangent = {0, 0, 1};
    p.normal = {1, 0, 0};
    p.radiusMm = 12.5;
    const auto cams = flyoverCameras(p, FlyoverParams{});
    EXPECT_NEAR(distance(cams[0].position, Vec3d(22.5, 20, 30)), 0.0, 1e-12);
    EXPECT_NEAR(distance(cams[1].position, Vec3d(-2.5, 20, 30)), 0.0, 1e-12);
}

TEST(FlyoverCameras, NearPlaneIsElevationMinusOffset)
{
    CenterlinePoint p;
    p.tangent = {0, 1, 0};
    p.normal = {0, 0, 1};
    p.radiusMm = 8.0;
    FlyoverParams params;  // fov 90: h = D = 8
    params.clipOffsetFraction = 0.5;
    auto cams = flyoverCameras(p, params);
    EXPECT_NEAR(cams[0].nearMm, 8.0 - 4.0, 1e-12);
    EXPECT_NEAR(cams[1].nearMm, 8.0 - 4.0, 1e-12);

    params.clipOffsetMm = 1.5;  // overrides the fraction
    cams = flyoverCameras(p, params);
    EXPECT_NEAR(cams[0].nearMm, 8.0 - 1.5, 1e-12);
    EXPECT_NEAR(cams[1].nearMm, 8.0 - 1.5, 1e-12);

    params.clipOffsetMm = 0.0;  // near plane exactly on the centerline (thesis V.B)
    cams = flyoverCameras(p, params);
    EXPECT_NEAR(cams[0].nearMm, distance(cams[0].position, p.positionMm), 1e-12);

    params.clipOffsetMm = 20.0;  // offset beyond the camera: clamped to 0
    cams = flyoverCameras(p, params);
    EXPECT_EQ(cams[0].nearMm, 0.0);
    EXPECT_EQ(cams[1].nearMm, 0.0);

    params.fovDeg = 60.0;
    params.clipOffsetMm = 2.0;
    cams = flyoverCameras(p, params);
    EXPECT_NEAR(cams[0].nearMm, 8.0 / std::tan(PI / 6.0) - 2.0, 1e-12);
}

TEST(FlyoverCameras, TangentProjectsRightWhenLeftToRightAndLeftOtherwise)
{
    std::mt19937 rng(77);
    for (int i = 0; i < 500; ++i) {
        const CenterlinePoint p = randomPoint(rng);
        for (const bool leftToRight : {true, false}) {
            FlyoverParams params;
            params.leftToRight = leftToRight;
            params.rollDeg = 37.0 * i;
            const auto cams = flyoverCameras(p, params);
            for (int k = 0; k < 2; ++k) {
                const Projection q = project(cams[std::size_t(k)], p.positionMm + p.tangent * (0.5 * p.radiusMm));
                SCOPED_TRACE("seed 77 #" + std::to_string(i) + " camera " + std::to_string(k) +
                             (leftToRight ? " left-to-right" : " right-to-left"));
                EXPECT_GT(q.depth, 0.0);
                if (leftToRight) EXPECT_GT(q.x, 0.1);
                else EXPECT_LT(q.x, -0.1);
                EXPECT_NEAR(q.y, 0.0, 1e-9);
            }
        }
    }
}

TEST(FlyoverCameras, RollRotatesBothCamerasAboutTheTangent)
{
    std::mt19937 rng(99);
    for (int i = 0; i < 200; ++i) {
        const CenterlinePoint p = randomPoint(rng);
        const double roll = -170.0 + 340.0 * (i / 199.0);
        FlyoverParams params;
        const auto base = flyoverCameras(p, params);
        params.rollDeg = roll;
        const auto rolled = flyoverCameras(p, params);
        for (int k = 0; k < 2; ++k) {
            const Vec3d a = base[std::size_t(k)].position - p.positionMm;
            const Vec3d b = rolled[std::size_t(k)].position - p.positionMm;
            // Signed angle from a to b about the tangent (right-hand rule).
            const double signedDeg = degrees(std::atan2(dot(p.tangent, cross(a, b)), dot(a, b)));
            EXPECT_NEAR(signedDeg, roll, 1e-7) << "seed 99 #" << i << " camera " << k;
            EXPECT_NEAR(dot(b, p.tangent), 0.0, 1e-9);
        }
    }
    // A half turn swaps the two cameras.
    const CenterlinePoint p = randomPoint(rng);
    FlyoverParams params;
    const auto base = flyoverCameras(p, params);
    params.rollDeg = 180.0;
    const auto half = flyoverCameras(p, params);
    EXPECT_NEAR(distance(base[0].position, half[1].position), 0.0, 1e-9);
    EXPECT_NEAR(distance(base[0].up, half[1].up), 0.0, 1e-9);
    EXPECT_NEAR(distance(base[0].right, half[1].right), 0.0, 1e-9);
}

TEST(FlyoverCameras, HelicalCenterlineViewNeverSpins)
{
    // Helix of radius a and pitch 2*pi*b, sampled every 1 mm of arc length.
    const double a = 20.0, b = 6.0, c = std::hypot(a, b);
    Centerline line;
    line.stepMm = 1.0;
    const int n = 600;  // ~ 4.5 turns
    for (int i = 0; i < n; ++i) {
        const double s = i * line.stepMm / c;
        CenterlinePoint p;
        p.positionMm = {a * std::cos(s), a * std::sin(s), b * s};
        p.radiusMm = 8.0;
        line.points.push_back(p);
    }
    computeTangentsAndNormals(line);
    FlyoverParams params;
    params.rollDeg = 25.0;
    double maxForwardTurn = 0, maxUpTurn = 0;
    std::array<Camera, 2> prev = flyoverCameras(line.points[0], params);
    for (int i = 1; i < n; ++i) {
        const auto cams = flyoverCameras(line.points[std::size_t(i)], params);
        for (int k = 0; k < 2; ++k) {
            maxForwardTurn = std::max(maxForwardTurn, angleDeg(prev[std::size_t(k)].forward, cams[std::size_t(k)].forward));
            maxUpTurn = std::max(maxUpTurn, angleDeg(prev[std::size_t(k)].up, cams[std::size_t(k)].up));
        }
        prev = cams;
    }
    // The tangent itself turns by kappa * step = a / (a^2 + b^2) rad per mm (~2.6 deg here); a
    // spinning frame would jump by tens of degrees.
    const double tangentTurnDeg = degrees(a / (c * c));
    RecordProperty("maxForwardTurnDeg", std::to_string(maxForwardTurn));
    RecordProperty("maxUpTurnDeg", std::to_string(maxUpTurn));
    SCOPED_TRACE("helix a=" + std::to_string(a) + " b=" + std::to_string(b) + " tangent turn/step " +
                 std::to_string(tangentTurnDeg) + " deg");
    EXPECT_LT(maxForwardTurn, 10.0);
    EXPECT_LT(maxUpTurn, 10.0);
    EXPECT_LT(maxForwardTurn, 2.0 * tangentTurnDeg);
    EXPECT_LT(maxUpTurn, 2.0 * tangentTurnDeg);
}

TEST(FlyoverCameras, RejectsBadInput)
{
    CenterlinePoint p;
    p.tangent = {0, 0, 1};
    p.normal = {1, 0, 0};
    p.radiusMm = 5;
    FlyoverParams params;
    params.fovDeg = 0;
    EXPECT_THROW(flyoverCameras(p, params), ParameterError);
    params.fovDeg = 180;
    EXPECT_THROW(flyoverCameras(p, params), ParameterError);
    params.fovDeg = std::nan("");
    EXPECT_THROW(flyoverCameras(p, params), ParameterError);
    params = FlyoverParams{};
    p.radiusMm = -1;
    EXPECT_THROW(flyoverCameras(p, params), InputError);
    p.radiusMm = 5;
    p.normal = {0, 0, 2};  // parallel to the tangent
    EXPECT_THROW(flyoverCameras(p, params), InputError);
}

TEST(OverviewCamera, AllBoxCornersProjectInsideTheImage)
{
    const std::vector<std::pair<Vec3d, Vec3d>> boxes = {
        {{0, 0, 0}, {100, 100, 100}}, {{-50, 10, 200}, {150, 40, 260}}, {{5, 5, 5}, {5.5, 300, 6}}};
    std::mt19937 rng(5);
    for (const auto& box : boxes) {
        for (int i = 0; i < 50; ++i) {
            const Vec3d dir = randomUnit(rng);
            const Vec3d up = randomUnit(rng);
            for (const double fov : {30.0, 60.0, 90.0}) {
                const Camera c = overviewCamera(box.first, box.second, dir, up, fov);
                expectOrthonormalRightHanded(c, "overview");
                EXPECT_EQ(c.nearMm, 0.0);
                EXPECT_NEAR(distance(c.forward, dir), 0.0, 1e-9);
                for (int k = 0; k < 8; ++k) {
                    const Vec3d corner{(k & 1) ? box.second.x : box.first.x,
                                       (k & 2) ? box.second.y : box.first.y,
                                       (k & 4) ? box.second.z : box.first.z};
                    const Projection q = project(c, corner);
                    SCOPED_TRACE("seed 5 #" + std::to_string(i) + " fov " + std::to_string(fov) +
                                 " corner " + std::to_string(k));
                    EXPECT_GT(q.depth, 0.0);
                    EXPECT_LE(std::fabs(q.x), 1.0);
                    EXPECT_LE(std::fabs(q.y), 1.0);
                }
            }
        }
    }
}

TEST(PixelDirection, CornersCentreAndDepthScale)
{
    const Camera c = lookAt({1, 2, 3}, {1, 12, 3}, {0, 0, 1}, 60.0);
    const double t = std::tan(PI / 6.0);
    // Centre of a 200 x 100 image: the optical axis; corners at +-aspect*tan, +-tan.
    EXPECT_NEAR(distance(pixelDirection(c, 200, 100, 100, 50), c.forward), 0.0, 1e-12);
    EXPECT_NEAR(distance(pixelDirection(c, 200, 100, 0, 0), c.forward - c.right * (2 * t) + c.up * t), 0.0, 1e-12);
    EXPECT_NEAR(distance(pixelDirection(c, 200, 100, 200, 100), c.forward + c.right * (2 * t) - c.up * t), 0.0, 1e-12);
    std::mt19937 rng(8);
    std::uniform_real_distribution<double> u(0.0, 100.0);
    for (int i = 0; i < 100; ++i) EXPECT_NEAR(dot(pixelDirection(c, 100, 80, u(rng), u(rng)), c.forward), 1.0, 1e-12);
}

TEST(FlyoverCameras, CuttingLineRollPutsADirectionWhereTheViewsMeet)
{
    std::mt19937 rng(4242);
    for (int i = 0; i < 300; ++i) {
        const CenterlinePoint p = randomPoint(rng);
        Vec3d dir = randomUnit(rng);
        if (length(cross(dir, p.tangent)) < 0.05) continue;
        FlyoverParams params;
        params.rollDeg = cuttingLineRollDeg(p, dir);
        EXPECT_GT(params.rollDeg, -180.0 - 1e-9);
        EXPECT_LE(params.rollDeg, 180.0 + 1e-9);
        const auto cams = flyoverCameras(p, params);
        for (int k = 0; k < 2; ++k)
            EXPECT_NEAR(dot(cams[std::size_t(k)].forward, dir), 0.0, 1e-9) << "seed 4242 #" << i;
    }
    CenterlinePoint p;
    p.tangent = {0, 0, 1};
    p.normal = {1, 0, 0};
    p.radiusMm = 5;
    EXPECT_THROW(cuttingLineRollDeg(p, {0, 0, 3}), InputError);
}

TEST(FlythroughCamera, LooksAlongTangentWithNormalUp)
{
    CenterlinePoint p;
    p.positionMm = {1, 2, 3};
    p.tangent = normalize(Vec3d{1, 1, 0});
    p.normal = {0, 0, 1};
    const Camera fwd = flythroughCamera(p, true, 70.0);
    const Camera back = flythroughCamera(p, false, 70.0);
    expectOrthonormalRightHanded(fwd, "forward");
    expectOrthonormalRightHanded(back, "backward");
    EXPECT_EQ(fwd.position, p.positionMm);
    EXPECT_NEAR(distance(fwd.forward, p.tangent), 0.0, EPS);
    EXPECT_NEAR(distance(back.forward, -p.tangent), 0.0, EPS);
    EXPECT_NEAR(distance(fwd.up, p.normal), 0.0, EPS);
    EXPECT_NEAR(distance(back.up, p.normal), 0.0, EPS);
    EXPECT_EQ(fwd.nearMm, 0.0);
    EXPECT_EQ(fwd.fovDeg, 70.0);
}

} // namespace
} // namespace flyover
