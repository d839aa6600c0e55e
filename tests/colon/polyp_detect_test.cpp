// Polyp candidates on analytic walls (colon/polyp_detect.h): the shape index of known shapes,
// a cap on a tube's wall found where it is with its size, and no candidate on a plain wall or
// on a fold-like ridge.
#include "colon/polyp_detect.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace {

using namespace flyover;
using openvdb::Vec3d;

constexpr double TUBE_RADIUS_MM = 20.0;
constexpr double TUBE_HALF_LENGTH_MM = 35.0;

/// Signed distance (negative in the lumen) of a capsule-shaped lumen along z: a tube whose
/// round ends are cups seen from inside.
double tubeMm(const Vec3d& p)
{
    const double z = std::clamp(p.z(), -TUBE_HALF_LENGTH_MM, TUBE_HALF_LENGTH_MM);
    return std::sqrt(p.x() * p.x() + p.y() * p.y() + (p.z() - z) * (p.z() - z)) - TUBE_RADIUS_MM;
}

/// A ball of tissue of `radiusMm` centred on the wall at +x (the phantom's polyp).
double withCap(const Vec3d& p, double radiusMm)
{
    const Vec3d c(TUBE_RADIUS_MM, 0, 0);
    return std::max(tubeMm(p), radiusMm - (p - c).length());
}

/// A fold: a ring of tissue of half-thickness `halfMm` round the wall at z = 0 over the
/// angles |phi| <= halfAngleRad (a partial fold with round ends), or the whole way round.
double withFold(const Vec3d& p, double halfMm, double halfAngleRad)
{
    const double phi = std::clamp(std::atan2(p.y(), p.x()), -halfAngleRad, halfAngleRad);
    const Vec3d onRim(TUBE_RADIUS_MM * std::cos(phi), TUBE_RADIUS_MM * std::sin(phi), 0);
    return std::max(tubeMm(p), halfMm - (p - onRim).length());
}

openvdb::FloatGrid::Ptr grid(const test::DistanceFn& f, double voxelMm)
{
    const double r = TUBE_RADIUS_MM + 4, z = TUBE_HALF_LENGTH_MM + TUBE_RADIUS_MM + 4;
    return test::sampleSdf(f, Vec3d(-r, -r, -z), Vec3d(r, r, z), voxelMm);
}

std::string describe(const PolypDetection& d)
{
    std::ostringstream os;
    os << d.candidates.size() << " candidate(s):";
    for (const PolypRegion& r : d.candidates)
        os << " [at " << r.centroidMm.x << "," << r.centroidMm.y << "," << r.centroidMm.z << " size " << r.sizeMm
           << " height " << r.heightMm << " elong " << r.elongation << " SI " << r.meanShapeIndex << " score "
           << r.score << "]";
    os << "; dropped " << d.dropped.size() << ", surface voxels " << d.surfaceVoxels << ", seeds " << d.seedVoxels;
    return os.str();
}

TEST(PolypShape, ShapeIndexOfKnownShapes)
{
    EXPECT_DOUBLE_EQ(shapeIndexOf(0.2, 0.2), 1.0);    // cap
    EXPECT_DOUBLE_EQ(shapeIndexOf(-0.2, -0.2), 0.0);  // cup
    EXPECT_DOUBLE_EQ(shapeIndexOf(0.2, 0.0), 0.75);   // ridge
    EXPECT_DOUBLE_EQ(shapeIndexOf(0.0, -0.2), 0.25);  // rut
    EXPECT_DOUBLE_EQ(shapeIndexOf(0.2, -0.2), 0.5);   // saddle
    EXPECT_DOUBLE_EQ(shapeIndexOf(0.0, 0.2), 0.75);   // order does not matter
}

TEST(PolypShape, WallOfTheTubeIsARutAndTheCapACap)
{
    const double h = 0.75;
    const auto sdf = grid([](const Vec3d& p) { return withCap(p, 5.0); }, h);
    // The tube's wall at -x: a rut of curvedness 1/(sqrt(2) R).
    const WallShape wall = wallShapeAt(*sdf, sdf->transform().worldToIndexCellCentered(Vec3d(-TUBE_RADIUS_MM, 0, 0)));
    EXPECT_NEAR(wall.shapeIndex, 0.25, 0.03);
    EXPECT_NEAR(wall.curvednessPerMm, 1.0 / (std::sqrt(2.0) * TUBE_RADIUS_MM), 0.01);
    EXPECT_GT(wall.normal.x, 0.95) << "the normal points into the lumen (+x at the -x wall)";
    // The cap's top, 5 mm into the lumen from the wall: a cap of curvedness 1/5.
    const WallShape top = wallShapeAt(*sdf, sdf->transform().worldToIndexCellCentered(Vec3d(TUBE_RADIUS_MM - 5.0, 0, 0)));
    EXPECT_NEAR(top.shapeIndex, 1.0, 0.03);
    EXPECT_NEAR(top.curvednessPerMm, 0.2, 0.03);
    EXPECT_LT(top.normal.x, -0.95);
    EXPECT_NEAR(top.pointMm.x, TUBE_RADIUS_MM - 5.0, 0.2);
}

TEST(PolypDetect, CapOnTheWallFoundWithItsSize)
{
    for (const double h : {0.75, 1.0}) {
        for (const double radius : {3.0, 5.0, 8.0}) {
            const auto sdf = grid([&](const Vec3d& p) { return withCap(p, radius); }, h);
            const PolypDetection d = detectPolyps(*sdf, PolypParams{});
            const std::string what = "cap of radius " + std::to_string(radius) + " mm at voxel " + std::to_string(h) +
                                     " mm: " + describe(d);
            ASSERT_EQ(d.candidates.size(), 1u) << what;
            const PolypRegion& c = d.candidates[0];
            // On the cap or inside it.
            EXPECT_LE(distance(c.centroidMm, flyover::Vec3d{TUBE_RADIUS_MM, 0, 0}), radius + 0.5) << what;
            EXPECT_NEAR(c.sizeMm, 2 * radius, std::max(1.5, 0.2 * 2 * radius)) << what;
            EXPECT_NEAR(c.heightMm, radius, std::max(1.0, 0.25 * radius)) << what;
            const double hemisphereMm3 = 2.0 / 3.0 * PI * radius * radius * radius;
            EXPECT_NEAR(c.volumeMm3, hemisphereMm3, 0.5 * hemisphereMm3 + 10 * h * h * h) << what;
            EXPECT_EQ(c.morphology, "sessile") << what;
            EXPECT_LT(c.upDir.x, -0.9) << "up points into the lumen, -x: " << what;
            EXPECT_GT(c.score, 0.5) << what;
            EXPECT_LE(c.score, 1.0) << what;
        }
    }
}

TEST(PolypDetect, PlainWallGivesNoCandidate)
{
    const auto sdf = grid(tubeMm, 0.75);
    const PolypDetection d = detectPolyps(*sdf, PolypParams{});
    EXPECT_TRUE(d.candidates.empty()) << describe(d);
    EXPECT_GT(d.surfaceVoxels, 10000u);
}

TEST(PolypDetect, FoldLikeRidgeGivesNoCandidate)
{
    for (const double halfAngle : {PI, 0.6 * PI, 0.3 * PI}) {
        const auto sdf = grid([&](const Vec3d& p) { return withFold(p, 2.5, halfAngle); }, 0.75);
        const PolypDetection d = detectPolyps(*sdf, PolypParams{});
        EXPECT_TRUE(d.candidates.empty()) << "fold over +-" << halfAngle << " rad: " << describe(d);
    }
}

TEST(PolypDetect, BadParametersRefusedByName)
{
    const auto sdf = grid(tubeMm, 1.5);
    PolypParams p;
    p.shapeIndexGrow = 0.95;  // above the seed's 0.9
    try {
        detectPolyps(*sdf, p);
        FAIL() << "expected a ParameterError";
    } catch (const ParameterError& e) {
        EXPECT_NE(std::string(e.what()).find("polyps.shape_index_grow"), std::string::npos) << e.what();
    }
}

} // namespace

namespace {

TEST(PolypDetect, CapBesideAFoldStillFound)
{
    // A whole fold round the wall at z = 0 and a cap 1 mm from it along the tube (the
    // phantom's polyps between folds).
    const double radius = 4.0, half = 2.5;
    const Vec3d capCentre(TUBE_RADIUS_MM, 0, half + 1.0 + radius);
    const auto sdf = grid(
        [&](const Vec3d& p) { return std::max(withFold(p, half, PI), radius - (p - capCentre).length()); }, 0.75);
    const PolypDetection d = detectPolyps(*sdf, PolypParams{});
    ASSERT_EQ(d.candidates.size(), 1u) << describe(d);
    const PolypRegion& c = d.candidates[0];
    EXPECT_LE(distance(c.centroidMm, flyover::Vec3d{capCentre.x(), capCentre.y(), capCentre.z()}), radius + 0.5)
        << describe(d);
    EXPECT_NEAR(c.sizeMm, 2 * radius, 2.0) << describe(d);
}

} // namespace
