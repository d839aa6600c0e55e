// Lumen segmentation against noisy HU phantoms with analytic ground truth (style.md §12).
#include "volume/segment.h"

#include "test_shapes.h"
#include "volume/centerline.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <openvdb/tools/Interpolation.h>

#include <tbb/task_arena.h>

#include <chrono>
#include <cmath>
#include <iostream>
#include <string>
#include <vector>

namespace flyover {
namespace {

using test::Axis;
using test::HuFeature;
using test::HuPhantom;

constexpr double PI = 3.14159265358979323846;

/// Body of 100 x 100 x 180 voxels at 1 mm in a rotated, translated frame.
HuPhantom basePhantom(std::uint64_t seed)
{
    HuPhantom ph;
    ph.frame = test::makeFrame(1.0, true);
    ph.bodyIndex = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(99, 99, 179));
    ph.seed = seed;
    return ph;
}

// A radius-8-voxel air tube: 130 mm long axis, about 28 mL with its caps. The axis is off the
// voxel lattice so that no voxel centre lies exactly on the analytic surface (such voxels are
// inside or outside by the toss of the noise, which would bias the Dice count).
constexpr double TUBE_X = 50.3, TUBE_Y = 35.2;
HuFeature colonTube()
{
    return {"colon", Axis::straight({TUBE_X, TUBE_Y, 20}, {TUBE_X, TUBE_Y, 150}), 8.0, -1000};
}
// About 33 mL; its air candidates (< -800 HU) about 29 mL, above minComponentMl.
HuFeature lungBlob() { return {"lung", Axis::sphere({50, 72, 140}), 20.0, -850}; }
std::vector<HuFeature> gasPockets()
{
    return {{"pocket1", Axis::sphere({25, 75, 40}), 3.0, -1000},
            {"pocket2", Axis::sphere({75, 75, 60}), 3.0, -1000},
            {"pocket3", Axis::sphere({20, 20, 100}), 3.0, -1000}};
}
// Air reaching through the body surface at x = 99.
HuFeature outsideTube() { return {"outside", Axis::straight({85, 80, 40}, {130, 80, 40}), 5.0, -1000}; }

double tubeVolumeMl(double lengthMm, double radiusMm)
{
    return (PI * radiusMm * radiusMm * lengthMm + 4.0 / 3.0 * PI * std::pow(radiusMm, 3)) / 1000.0;
}

SegmentParams midpointParams()
{
    SegmentParams p;
    p.surfaceIsoHu = -480.0;  // exact midpoint of this phantom's tissue (+40) and air (-1000)
    return p;
}

/// The component whose centroid (world) is nearest to the local point, or nullptr.
const AirComponent* componentNear(const LumenSegmentation& seg, const test::Frame& frame,
                                  const Vec3d& localMm, double toleranceMm)
{
    const AirComponent* best = nullptr;
    double bestD = toleranceMm;
    for (const AirComponent& c : seg.components) {
        const double d = distance(frame.localFromWorld(c.centroidMm), localMm);
        if (d <= bestD) {
            bestD = d;
            best = &c;
        }
    }
    return best;
}

std::string listComponents(const LumenSegmentation& seg)
{
    std::string s;
    for (const AirComponent& c : seg.components)
        s += "  " + c.reason + " " + std::to_string(c.volumeMl) + " mL mean " +
             std::to_string(c.meanHu) + " HU\n";
    return s;
}

TEST(SegmentLumen, KeepsTubeAndDropsLungPocketsAndBorderAir)
{
    HuPhantom ph = basePhantom(11);
    ph.features = {colonTube(), lungBlob(), outsideTube()};
    for (const HuFeature& f : gasPockets()) ph.features.push_back(f);
    const auto hu = test::makeHuGrid(ph);
    const LumenSegmentation seg = segmentLumen(*hu, midpointParams());
    SCOPED_TRACE(ph.describe() + "\ncomponents:\n" + listComponents(seg));

    int kept = 0;
    for (const AirComponent& c : seg.components) kept += c.kept ? 1 : 0;
    EXPECT_EQ(kept, 1);

    const AirComponent* colon = componentNear(seg, ph.frame, {TUBE_X, TUBE_Y, 85}, 2.0);
    ASSERT_NE(colon, nullptr);
    EXPECT_TRUE(colon->kept);
    EXPECT_EQ(colon->reason, "colon");
    // Air candidates stop about 0.5 voxel inside the blurred edge (-800 HU), so the component
    // is a little smaller than the tube; the sub-voxel lumen volume matches it closely.
    const double trueMl = tubeVolumeMl(130, 8);
    EXPECT_GT(colon->volumeMl, 0.8 * trueMl);
    EXPECT_LT(colon->volumeMl, 1.0 * trueMl);
    EXPECT_LT(colon->meanHu, -950);
    EXPECT_NEAR(seg.lumenVolumeMl, trueMl, 0.02 * trueMl);
    // World bbox of the kept air contains the world image of the axis' middle point.
    const Vec3d mid = ph.frame.worldFromLocal({TUBE_X, TUBE_Y, 85});
    for (int k = 0; k < 3; ++k) {
        EXPECT_LT(colon->minMm[k], mid[k]);
        EXPECT_GT(colon->maxMm[k], mid[k]);
    }

    const AirComponent* lung = componentNear(seg, ph.frame, {50, 72, 140}, 2.0);
    ASSERT_NE(lung, nullptr);
    EXPECT_FALSE(lung->kept);
    EXPECT_EQ(lung->reason, "lung");
    EXPECT_GT(lung->meanHu, -900);

    for (const HuFeature& f : gasPockets()) {
        const AirComponent* c = componentNear(seg, ph.frame, f.axis.start(), 1.0);
        ASSERT_NE(c, nullptr) << f.name;
        EXPECT_FALSE(c->kept) << f.name;
        EXPECT_EQ(c->reason, "small") << f.name;
    }

    int border = 0;
    for (const AirComponent& c : seg.components) border += c.reason == "border" ? 1 : 0;
    EXPECT_GE(border, 1);
    const AirComponent* outside = componentNear(seg, ph.frame, {92, 80, 40}, 3.0);
    ASSERT_NE(outside, nullptr);
    EXPECT_EQ(outside->reason, "border");
}

TEST(SegmentLumen, MaskDiceAgainstAnalyticTube)
{
    for (std::uint64_t seed : {1u, 2u}) {
        HuPhantom ph = basePhantom(seed);
        ph.features = {colonTube()};
        SCOPED_TRACE(ph.describe());
        const auto hu = test::makeHuGrid(ph);
        const SegmentParams params = midpointParams();
        const LumenSegmentation seg = segmentLumen(*hu, params);
        ASSERT_TRUE(seg.mask);
        EXPECT_EQ(seg.mask->getName(), "lumen_mask");

        std::size_t both = 0, truth = 0, found = 0;
        auto maskAcc = seg.mask->getConstAccessor();
        for (auto it = ph.bodyIndex.begin(); it; ++it) {
            const openvdb::Coord ijk = *it;
            const Vec3d p{double(ijk.x()), double(ijk.y()), double(ijk.z())};
            const bool inside = test::featureDistanceMm(ph.features[0], p * ph.frame.voxelMm) < 0;
            const bool inMask = maskAcc.isValueOn(ijk);
            truth += inside;
            found += inMask;
            both += inside && inMask;
        }
        EXPECT_EQ(found, seg.mask->activeVoxelCount());  // nothing outside the body
        const double dice = 2.0 * double(both) / double(truth + found);
        EXPECT_GE(dice, 0.99) << "true " << truth << " found " << found << " both " << both;

        // The default iso-value (-500 HU) sits 20 HU off this phantom's midpoint: still fine.
        const LumenSegmentation seg500 = segmentLumen(*hu, SegmentParams{});
        std::size_t both500 = 0;
        for (auto it = seg500.mask->cbeginValueOn(); it; ++it) {
            const openvdb::Coord ijk = it.getCoord();
            const Vec3d p{double(ijk.x()), double(ijk.y()), double(ijk.z())};
            both500 += test::featureDistanceMm(ph.features[0], p * ph.frame.voxelMm) < 0;
        }
        const double dice500 =
            2.0 * double(both500) / double(truth + seg500.mask->activeVoxelCount());
        EXPECT_GE(dice500, 0.98);
        std::cout << "[ dice ] seed " << seed << ": " << dice << " at the midpoint iso-value, "
                  << dice500 << " at the default -500 HU\n";
    }
}

TEST(SegmentLumen, SdfMatchesAnalyticDistance)
{
    HuPhantom ph = basePhantom(7);
    ph.features = {colonTube()};
    SCOPED_TRACE(ph.describe());
    const auto hu = test::makeHuGrid(ph);
    SegmentParams params = midpointParams();
    const LumenSegmentation seg = segmentLumen(*hu, params);
    const auto& sdf = *seg.sdf;
    const double h = ph.frame.voxelMm;

    EXPECT_EQ(sdf.getName(), "lumen_sdf");
    EXPECT_EQ(sdf.getGridClass(), openvdb::GRID_LEVEL_SET);
    EXPECT_NEAR(sdf.background(), params.bandVoxels * h, 1e-6);
    EXPECT_TRUE(sdf.transform() == hu->transform());
    EXPECT_FALSE(sdf.tree().hasActiveTiles());

    // Points at known signed distance from the analytic surface, along the tube's middle.
    openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(sdf);
    double worstNear = 0, worstDeep = 0;
    for (double z = 50; z <= 120; z += 7.3)
        for (double angle = 0; angle < 2 * PI; angle += 0.37)
            for (double delta : {-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0}) {
                const double rho = 8.0 + delta * h;
                const Vec3d local{TUBE_X + rho * std::cos(angle), TUBE_Y + rho * std::sin(angle), z};
                const Vec3d w = ph.frame.worldFromLocal(local);
                const double v = sampler.wsSample(openvdb::Vec3d(w.x, w.y, w.z));
                worstNear = std::max(worstNear, std::abs(v - delta * h));
                EXPECT_NEAR(v, delta * h, 0.2 * h) << "z " << z << " angle " << angle << " delta " << delta;
            }
    // Deep inside: voxels within 1.5 voxels of the axis, compared at their centres (trilinear
    // interpolation of the distance's ridge would add its own error). First-order fast sweeping
    // rounds off the ridge where characteristics converge: about half a voxel short here.
    auto acc = sdf.getConstAccessor();
    for (int z = 50; z <= 120; z += 5)
        for (int x = 48; x <= 53; ++x)
            for (int y = 33; y <= 38; ++y) {
                const double rho = std::hypot(x * h - TUBE_X, y * h - TUBE_Y);
                if (rho > 1.5 * h) continue;
                const double v = acc.getValue(openvdb::Coord(x, y, z));
                worstDeep = std::max(worstDeep, std::abs(v - (rho - 8.0)));
                EXPECT_NEAR(v, rho - 8.0, 0.75 * h) << "voxel " << x << "," << y << "," << z;
            }
    std::cout << "[ sdf error ] near surface max " << worstNear << " mm, near the axis max "
              << worstDeep << " mm (voxel " << h << " mm)\n";

    // Sign: negative for every voxel more than a voxel inside, positive more than one outside.
    std::size_t checked = 0;
    for (auto it = ph.bodyIndex.begin(); it; ++it) {
        const openvdb::Coord ijk = *it;
        const Vec3d p{double(ijk.x()), double(ijk.y()), double(ijk.z())};
        const double d = test::featureDistanceMm(ph.features[0], p * h);
        if (d < -h) {
            ++checked;
            ASSERT_TRUE(acc.isValueOn(ijk)) << ijk;
            ASSERT_LT(acc.getValue(ijk), 0.0f) << ijk;
        } else if (d > h) {
            ASSERT_GT(acc.getValue(ijk), 0.0f) << ijk;
        }
    }
    EXPECT_GT(checked, 20000u);
}

TEST(SegmentLumen, FractionDropsMuchSmallerAir)
{
    HuPhantom ph = basePhantom(3);
    ph.features = {colonTube(), {"side", Axis::straight({20, 75, 30}, {20, 75, 90}), 4.0, -1000}};
    SCOPED_TRACE(ph.describe());
    SegmentParams params = midpointParams();
    params.minComponentMl = 1.0;
    params.keepFraction = 0.5;
    const LumenSegmentation seg = segmentLumen(*test::makeHuGrid(ph), params);
    const AirComponent* colon = componentNear(seg, ph.frame, {TUBE_X, TUBE_Y, 85}, 2.0);
    const AirComponent* side = componentNear(seg, ph.frame, {20, 75, 60}, 2.0);
    ASSERT_NE(colon, nullptr);
    ASSERT_NE(side, nullptr);
    EXPECT_EQ(colon->reason, "colon");
    EXPECT_EQ(side->reason, "fraction");
    EXPECT_FALSE(side->kept);

    // With the default keepFraction both tubes are kept.
    params.keepFraction = 0.05;
    const LumenSegmentation both = segmentLumen(*test::makeHuGrid(ph), params);
    int kept = 0;
    for (const AirComponent& c : both.components) kept += c.kept ? 1 : 0;
    EXPECT_EQ(kept, 2);
}

TEST(SegmentLumen, NoColonThrowsInputErrorListingComponents)
{
    HuPhantom ph = basePhantom(5);
    ph.features = {lungBlob(), outsideTube()};
    for (const HuFeature& f : gasPockets()) ph.features.push_back(f);
    SCOPED_TRACE(ph.describe());
    const auto hu = test::makeHuGrid(ph);
    try {
        segmentLumen(*hu, midpointParams());
        FAIL() << "expected InputError";
    } catch (const InputError& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find("found 5 connected air component"), std::string::npos) << msg;
        EXPECT_NE(msg.find("lung"), std::string::npos) << msg;
        EXPECT_NE(msg.find("small"), std::string::npos) << msg;
        EXPECT_NE(msg.find("border"), std::string::npos) << msg;
        EXPECT_NE(msg.find(" mL"), std::string::npos) << msg;
    }

    // No air at all.
    ph.features.clear();
    EXPECT_THROW(segmentLumen(*test::makeHuGrid(ph), midpointParams()), InputError);
}

TEST(SegmentLumen, AdjacentPocketDoesNotLeakIntoLumen)
{
    // A gas pocket 2 mm of tissue away from the tube: inside the dilation shell of the lumen,
    // but a dropped component, so it must stay outside.
    HuPhantom ph = basePhantom(9);
    const Vec3d pocket{TUBE_X + 8 + 2 + 3, TUBE_Y, 85};
    ph.features = {colonTube(), {"pocket", Axis::sphere(pocket), 3.0, -1000}};
    SCOPED_TRACE(ph.describe());
    const LumenSegmentation seg = segmentLumen(*test::makeHuGrid(ph), midpointParams());
    const AirComponent* c = componentNear(seg, ph.frame, pocket, 1.0);
    ASSERT_NE(c, nullptr);
    EXPECT_EQ(c->reason, "small");

    auto maskAcc = seg.mask->getConstAccessor();
    auto sdfAcc = seg.sdf->getConstAccessor();
    int leaked = 0;
    for (int x = 58; x <= 68; ++x)
        for (int y = 30; y <= 40; ++y)
            for (int z = 80; z <= 90; ++z) {
                const openvdb::Coord ijk(x, y, z);
                if (distance(Vec3d(x, y, z), pocket) < 3.5 && maskAcc.isValueOn(ijk)) ++leaked;
            }
    EXPECT_EQ(leaked, 0);
    EXPECT_GT(sdfAcc.getValue(openvdb::Coord(63, 35, 85)), 0.0f);  // the pocket's centre voxel
    const double trueMl = tubeVolumeMl(130, 8);
    EXPECT_NEAR(seg.lumenVolumeMl, trueMl, 0.02 * trueMl);
}

TEST(SegmentLumen, RejectsBadInputAndParameters)
{
    HuPhantom ph = basePhantom(1);
    ph.features = {colonTube()};
    auto hu = test::makeHuGrid(ph);
    SegmentParams bad;
    bad.surfaceIsoHu = -900;  // below the air threshold
    EXPECT_THROW(segmentLumen(*hu, bad), ParameterError);
    bad = SegmentParams{};
    bad.keepFraction = std::nan("");
    EXPECT_THROW(segmentLumen(*hu, bad), ParameterError);
    bad = SegmentParams{};
    bad.bandVoxels = 0;
    EXPECT_THROW(segmentLumen(*hu, bad), ParameterError);

    auto aniso = hu->deepCopy();
    openvdb::math::Mat4d scale = openvdb::math::Mat4d::identity();
    scale.preScale(openvdb::Vec3d(0.7, 0.7, 1.25));
    aniso->setTransform(openvdb::math::Transform::createLinearTransform(scale));
    EXPECT_THROW(segmentLumen(*aniso, SegmentParams{}), InputError);
}

struct RecordingProgress : Progress {
    std::vector<double> fractions;
    bool cancel = false;
    void update(double fraction, const std::string&) override { fractions.push_back(fraction); }
    bool cancelled() const override { return cancel; }
};

TEST(SegmentLumen, ReportsProgressAndCancels)
{
    HuPhantom ph = basePhantom(1);
    ph.features = {colonTube()};
    const auto hu = test::makeHuGrid(ph);
    RecordingProgress progress;
    segmentLumen(*hu, midpointParams(), &progress);
    ASSERT_GE(progress.fractions.size(), 3u);
    for (std::size_t i = 1; i < progress.fractions.size(); ++i)
        EXPECT_GE(progress.fractions[i], progress.fractions[i - 1]);
    EXPECT_DOUBLE_EQ(progress.fractions.back(), 1.0);

    RecordingProgress cancelling;
    cancelling.cancel = true;
    EXPECT_THROW(segmentLumen(*hu, midpointParams(), &cancelling), Cancelled);
}

TEST(SegmentLumen, SameResultWithOneThread)
{
    HuPhantom ph = basePhantom(4);
    ph.features = {colonTube(), lungBlob()};
    const auto hu = test::makeHuGrid(ph);
    const LumenSegmentation a = segmentLumen(*hu, midpointParams());
    LumenSegmentation b;
    tbb::task_arena single(1);
    single.execute([&] { b = segmentLumen(*hu, midpointParams()); });
    ASSERT_EQ(a.components.size(), b.components.size());
    for (std::size_t i = 0; i < a.components.size(); ++i) {
        EXPECT_EQ(a.components[i].volumeMl, b.components[i].volumeMl);
        EXPECT_EQ(a.components[i].meanHu, b.components[i].meanHu);
        EXPECT_EQ(a.components[i].reason, b.components[i].reason);
    }
    EXPECT_EQ(a.lumenVolumeMl, b.lumenVolumeMl);
    EXPECT_EQ(a.sdf->activeVoxelCount(), b.sdf->activeVoxelCount());
    auto accB = b.sdf->getConstAccessor();
    std::size_t differ = 0;
    for (auto it = a.sdf->cbeginValueOn(); it; ++it) differ += accB.getValue(it.getCoord()) != *it;
    EXPECT_EQ(differ, 0u);
}

} // namespace
} // namespace flyover
