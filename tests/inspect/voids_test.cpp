// Internal voids of a solid part (inspect/voids.h) on analytic shapes with closed-form volumes.
#include "volume/error.h"
#include "volume/vec3.h"
#include "inspect/voids.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <functional>
#include <random>
#include <vector>

using namespace flyover;

namespace {

struct Scene {
    int n = 64;
    double voxelMm = 0.2;
    openvdb::Vec3d offsetMm{10.0, -5.0, 3.0};  // index -> world: x * voxel + offset
    double air = 1000, material = 5000, noise = 0;
    /// true where a point (continuous index coordinates) is material
    std::function<bool(const openvdb::Vec3d&)> solid;
};

/// Dense grid, every voxel active: grey = air + (material - air) x fraction (4^3 samples) + noise.
openvdb::FloatGrid::Ptr makeGrid(const Scene& s, uint32_t seed = 7)
{
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto xf = openvdb::math::Transform::createLinearTransform(s.voxelMm);
    xf->postTranslate(s.offsetMm);
    grid->setTransform(xf);
    std::mt19937 rng(seed);
    std::normal_distribution<double> gauss(0.0, 1.0);
    auto acc = grid->getAccessor();
    for (int z = 0; z < s.n; ++z)
        for (int y = 0; y < s.n; ++y)
            for (int x = 0; x < s.n; ++x) {
                int inside = 0;
                for (int a = 0; a < 4; ++a)
                    for (int b = 0; b < 4; ++b)
                        for (int c = 0; c < 4; ++c)
                            inside += s.solid({x + (a + 0.5) / 4 - 0.5, y + (b + 0.5) / 4 - 0.5, z + (c + 0.5) / 4 - 0.5});
                double g = s.air + (s.material - s.air) * inside / 64.0;
                if (s.noise > 0) g += s.noise * gauss(rng);
                acc.setValueOn(openvdb::Coord(x, y, z), static_cast<float>(g));
            }
    return grid;
}

// A block of material from 8 to 55 (index) on each axis.
bool inBlock(const openvdb::Vec3d& p)
{
    return p.x() > 7.5 && p.x() < 55.5 && p.y() > 7.5 && p.y() < 55.5 && p.z() > 7.5 && p.z() < 55.5;
}

} // namespace

TEST(Voids, SphereInBlockMeasuredByPartialVolume)
{
    const openvdb::Vec3d c(30.3, 31.6, 29.2);
    const double r = 6.0;
    Scene s;
    s.noise = 80;  // 2% of the contrast
    s.solid = [&](const openvdb::Vec3d& p) { return inBlock(p) && (p - c).length() > r; };
    const PartAnalysis a = analysePart(*makeGrid(s), VoidParams{}, "sphere.nii");
    EXPECT_EQ(a.thresholdSource, "otsu");
    ASSERT_EQ(a.voids.size(), 1u) << "one spherical void of radius 6 voxels";
    const VoidInfo& v = a.voids[0];
    const double vox3 = std::pow(s.voxelMm, 3);
    const double trueVolume = 4.0 / 3.0 * PI * r * r * r * vox3;
    EXPECT_NEAR(v.volumeMm3, trueVolume, 0.02 * trueVolume);
    EXPECT_NEAR(v.equivalentDiameterMm, 2 * r * s.voxelMm, 0.02 * 2 * r * s.voxelMm);
    EXPECT_EQ(v.kind, "pore");
    EXPECT_GT(v.sphericity, 0.9);
    EXPECT_LT(v.sphericity, 1.05);
    // centroid in world (LPS) = index * voxel + offset
    EXPECT_NEAR(v.centroidLps.x, c.x() * s.voxelMm + s.offsetMm.x(), 0.5 * s.voxelMm);
    EXPECT_NEAR(v.centroidLps.y, c.y() * s.voxelMm + s.offsetMm.y(), 0.5 * s.voxelMm);
    EXPECT_NEAR(v.centroidLps.z, c.z() * s.voxelMm + s.offsetMm.z(), 0.5 * s.voxelMm);
    // nearest face of the block: z = 7.5 from 29.2 -> 21.7 voxels
    EXPECT_NEAR(v.distanceToSurfaceMm, 21.7 * s.voxelMm, 1.0 * s.voxelMm);
    // max extent: distance between voxel centres across the sphere, a little under 2r
    EXPECT_GT(v.maxExtentMm, (2 * r - 2) * s.voxelMm);
    EXPECT_LE(v.maxExtentMm, 2 * r * s.voxelMm);
    const double block = 48.0 * 48.0 * 48.0 * vox3;
    EXPECT_NEAR(a.materialVolumeMm3, block - trueVolume, 0.001 * block);
    const double truePorosity = 100.0 * trueVolume / block;
    EXPECT_NEAR(a.porosityPercent, truePorosity, 0.01) << "porosity (percentage points)";
    ASSERT_TRUE(a.voidLabels && a.material && a.outsideAir);
    EXPECT_EQ(a.voidLabels->activeVoxelCount(), static_cast<openvdb::Index64>(v.voxels));
    EXPECT_EQ(a.voidLabels->tree().getValue(openvdb::Coord(30, 32, 29)), 1);
    EXPECT_TRUE(a.outsideAir->tree().isValueOn(openvdb::Coord(2, 2, 2)));
    EXPECT_TRUE(a.material->tree().isValueOn(openvdb::Coord(12, 12, 12)));
}

TEST(Voids, ThinDiscIsCrackAndSphereIsPore)
{
    // a disc 2 voxels thick, radius 14, tilted; a sphere of radius 4 elsewhere
    const openvdb::Vec3d dc(31.5, 24.0, 31.5), sc(31.0, 44.0, 31.0);
    const openvdb::Vec3d nrm = openvdb::Vec3d(0.3, 1.0, 0.2).unit();
    Scene s;
    s.noise = 80;
    s.solid = [&](const openvdb::Vec3d& p) {
        const openvdb::Vec3d d = p - dc;
        const double h = d.dot(nrm);
        const bool disc = std::abs(h) <= 1.0 && (d - nrm * h).length() <= 14.0;
        return inBlock(p) && !disc && (p - sc).length() > 4.0;
    };
    const PartAnalysis a = analysePart(*makeGrid(s), VoidParams{}, "disc.nii");
    ASSERT_EQ(a.voids.size(), 2u);
    const VoidInfo& disc = a.voids[0];  // the larger one: pi 14^2 2 = 1231 voxels vs 268
    EXPECT_EQ(disc.kind, "crack");
    EXPECT_NEAR(disc.volumeMm3, PI * 14 * 14 * 2 * std::pow(s.voxelMm, 3), 0.05 * PI * 14 * 14 * 2 * std::pow(s.voxelMm, 3));
    EXPECT_NEAR(disc.maxExtentMm, 28 * s.voxelMm, 2.0 * s.voxelMm);
    EXPECT_LT(disc.sphericity, 0.5);
    EXPECT_EQ(a.voids[1].kind, "pore");
}

TEST(Voids, AirJoinedToTheBorderIsOutside)
{
    // a sphere joined to the outside by a 2-voxel channel, and a through bore: no internal void
    Scene s;
    s.solid = [&](const openvdb::Vec3d& p) {
        const bool sphere = (p - openvdb::Vec3d(31, 31, 31)).length() < 6;
        const bool channel = std::abs(p.x() - 31) < 1.0 && std::abs(p.y() - 31) < 1.0 && p.z() > 31;
        const bool bore = std::hypot(p.x() - 16, p.y() - 16) < 3;
        return inBlock(p) && !sphere && !channel && !bore;
    };
    const PartAnalysis a = analysePart(*makeGrid(s), VoidParams{}, "open.nii");
    EXPECT_TRUE(a.voids.empty()) << a.voids.size() << " internal voids listed";
    EXPECT_EQ(a.smallVoidCount, 0);
    EXPECT_NEAR(a.porosityPercent, 0.0, 1e-3);
    EXPECT_TRUE(a.outsideAir->tree().isValueOn(openvdb::Coord(31, 31, 31))) << "the open sphere is outside air";
}

TEST(Voids, SmallVoidsAreCountedNotListed)
{
    Scene s;
    s.solid = [&](const openvdb::Vec3d& p) {
        return inBlock(p) && (p - openvdb::Vec3d(20, 20, 20)).length() > 0.7 && (p - openvdb::Vec3d(40, 40, 40)).length() > 5;
    };
    VoidParams params;
    params.minDiameterVoxels = 2.0;
    const PartAnalysis a = analysePart(*makeGrid(s), params, "small.nii");
    ASSERT_EQ(a.voids.size(), 1u);
    EXPECT_EQ(a.smallVoidCount, 1);
    EXPECT_GT(a.smallVoidVolumeMm3, 0.0);
    EXPECT_NEAR(a.voidVolumeMm3, a.voids[0].volumeMm3 + a.smallVoidVolumeMm3, 1e-9);
}

TEST(Voids, GreyRangeDoesNotMatter)
{
    Scene s;
    s.noise = 0;
    s.solid = [&](const openvdb::Vec3d& p) { return inBlock(p) && (p - openvdb::Vec3d(30, 30, 30)).length() > 5; };
    s.air = 100;
    s.material = 400;
    const PartAnalysis low = analysePart(*makeGrid(s), VoidParams{}, "low.nii");
    s.air = 20000;
    s.material = 60000;
    const PartAnalysis high = analysePart(*makeGrid(s), VoidParams{}, "high.nii");
    s.air = -1000;  // HU-like
    s.material = 1200;
    const PartAnalysis hu = analysePart(*makeGrid(s), VoidParams{}, "hu.nii");
    ASSERT_EQ(low.voids.size(), 1u);
    ASSERT_EQ(high.voids.size(), 1u);
    ASSERT_EQ(hu.voids.size(), 1u);
    EXPECT_NEAR(low.voids[0].volumeMm3, high.voids[0].volumeMm3, 1e-3 * high.voids[0].volumeMm3);
    EXPECT_NEAR(hu.voids[0].volumeMm3, high.voids[0].volumeMm3, 1e-3 * high.voids[0].volumeMm3);
    EXPECT_NEAR(low.porosityPercent, high.porosityPercent, 1e-3);
}

TEST(Voids, GivenThresholdIsUsed)
{
    Scene s;
    s.solid = [&](const openvdb::Vec3d& p) { return inBlock(p) && (p - openvdb::Vec3d(30, 30, 30)).length() > 5; };
    VoidParams params;
    params.threshold = 3000;
    const PartAnalysis a = analysePart(*makeGrid(s), params, "given.nii");
    EXPECT_EQ(a.thresholdSource, "given");
    EXPECT_EQ(a.threshold, 3000);
    EXPECT_EQ(a.voids.size(), 1u);
}

TEST(Voids, NoMaterialIsRefusedNamingTheSource)
{
    Scene s;
    s.noise = 50;
    s.solid = [](const openvdb::Vec3d&) { return false; };
    const auto grid = makeGrid(s);
    try {
        analysePart(*grid, VoidParams{}, "empty_scan.nii");
        FAIL() << "a scan of air only was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("empty_scan.nii"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("no material"), std::string::npos) << e.what();
    }
    VoidParams given;
    given.threshold = 3000;
    try {
        analysePart(*grid, given, "empty_scan.nii");
        FAIL() << "a scan of air only was accepted with a threshold";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("empty_scan.nii: no material"), std::string::npos) << e.what();
    }
}

TEST(Voids, AllMaterialIsRefusedNamingTheSource)
{
    Scene s;
    s.noise = 50;
    s.solid = [](const openvdb::Vec3d&) { return true; };
    const auto grid = makeGrid(s);
    EXPECT_THROW(analysePart(*grid, VoidParams{}, "solid.nii"), InputError);
    VoidParams given;
    given.threshold = 3000;
    try {
        analysePart(*grid, given, "solid.nii");
        FAIL() << "a scan of material only was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("solid.nii: all material"), std::string::npos) << e.what();
    }
    // a uniform grid
    s.noise = 0;
    try {
        analysePart(*makeGrid(s), VoidParams{}, "flat.nii");
        FAIL() << "a uniform grid was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("flat.nii"), std::string::npos) << e.what();
    }
}

TEST(Voids, BadGridsAndParametersAreRefused)
{
    Scene s;
    s.n = 24;
    s.solid = [](const openvdb::Vec3d& p) { return p.x() > 8 && p.x() < 16; };
    auto grid = makeGrid(s);
    grid->tree().setValueOn(openvdb::Coord(3, 3, 3), std::numeric_limits<float>::quiet_NaN());
    EXPECT_THROW(analysePart(*grid, VoidParams{}, "nan.nii"), InputError);
    EXPECT_THROW(analysePart(*openvdb::FloatGrid::create(0.0f), VoidParams{}, "none.nii"), InputError);
    // a 2D image (one slice)
    auto flat = openvdb::FloatGrid::create(0.0f);
    for (int y = 0; y < 20; ++y)
        for (int x = 0; x < 20; ++x) flat->tree().setValueOn(openvdb::Coord(x, y, 0), x > 10 ? 5000.0f : 1000.0f);
    EXPECT_THROW(analysePart(*flat, VoidParams{}, "slice.png"), InputError);
    VoidParams bad;
    bad.minDiameterVoxels = -1;
    EXPECT_THROW(analysePart(*makeGrid(s), bad, "x.nii"), ParameterError);
    bad = VoidParams{};
    bad.threshold = std::numeric_limits<double>::infinity();
    EXPECT_THROW(analysePart(*makeGrid(s), bad, "x.nii"), ParameterError);
}

TEST(Voids, MaxVoxelDistance)
{
    std::vector<openvdb::Vec3d> line;
    for (int i = 0; i < 10; ++i) line.emplace_back(i, 2 * i, 0);
    EXPECT_NEAR(maxVoxelDistance(line), std::sqrt(81.0 + 324.0), 1e-12);
    EXPECT_EQ(maxVoxelDistance({openvdb::Vec3d(1, 2, 3)}), 0.0);
    // > 3000 candidates: points on a sphere of radius 40 (diameter 80), approximated within 0.3%
    std::vector<openvdb::Vec3d> shell;
    std::mt19937 rng(3);
    std::normal_distribution<double> g;
    for (int i = 0; i < 20000; ++i) shell.push_back(openvdb::Vec3d(g(rng), g(rng), g(rng)).unit() * 40.0);
    shell.push_back(openvdb::Vec3d(0, 0, 41));
    shell.push_back(openvdb::Vec3d(0, 0, -41));  // the farthest pair: 82
    EXPECT_NEAR(maxVoxelDistance(shell), 82.0, 0.003 * 82.0);
    EXPECT_NEAR(equivalentDiameter(4.0 / 3.0 * PI * 27.0), 6.0, 1e-12);
}

