// The rectal tube (colon/rectal_tube.h): a colon whose rectum holds a catheter that leaves the
// body, from a noisy HU phantom and from masks; no tube reported where there is none; masks
// without a plausible colon refused.
#include "colon/rectal_tube.h"

#include "tests/shapes/test_shapes.h"
#include "volume/error.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <sstream>
#include <string>

namespace flyover {
namespace {

using test::Axis;
using test::HuFeature;
using test::HuPhantom;

// Local mm (1 mm voxels): body box 0..99 x 0..99 x 0..179. The colon is a U of radius 12: the
// rectum rises from z = 18 (the bottom of its cap) at x = 30.3. The tube comes from below the
// body (z = -20), crosses the body surface at z = 0, the tissue below the rectum (the anal
// canal), and ends inside the rectum at TUBE_TIP; its lumen is 6 mm wide, its wall 1.5 mm.
const Vec3d RECTUM_START{30.3, 50.2, 30};
constexpr double COLON_RADIUS = 12;
const Vec3d TUBE_OUTER{37.0, 50.6, -20};
const Vec3d TUBE_TIP{31.5, 50.6, 45};
constexpr double TUBE_LUMEN_RADIUS = 3.0, TUBE_WALL_RADIUS = 4.5;

HuFeature colon() { return {"colon", Axis::uBend(RECTUM_START, 100, 80, 20), COLON_RADIUS, -1000}; }
/// The wall: a solid rod, then the lumen painted over it. The lumen runs 6 mm past the wall's
/// end so that the tube is open at its tip.
HuFeature tubeWall() { return {"tube wall", Axis::straight(TUBE_OUTER, TUBE_TIP), TUBE_WALL_RADIUS, 200}; }
HuFeature tubeLumen()
{
    const Vec3d past = TUBE_TIP + normalize(TUBE_TIP - TUBE_OUTER) * 6.0;
    return {"tube lumen", Axis::straight(TUBE_OUTER, past), TUBE_LUMEN_RADIUS, -1000};
}

HuPhantom phantom(bool withTube)
{
    HuPhantom ph;
    ph.frame = test::makeFrame(1.0, true);
    ph.bodyIndex = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(99, 99, 179));
    ph.seed = 21;
    ph.features = {colon()};
    if (withTube) {
        ph.features.push_back(tubeWall());
        ph.features.push_back(tubeLumen());
    }
    return ph;
}

/// Where the tube's axis crosses the body surface (z = 0).
Vec3d truthEntry()
{
    const double t = (0.0 - TUBE_OUTER.z) / (TUBE_TIP.z - TUBE_OUTER.z);
    return TUBE_OUTER + (TUBE_TIP - TUBE_OUTER) * t;
}

double distanceToTubeAxis(const Vec3d& p)
{
    const Vec3d ab = TUBE_TIP - TUBE_OUTER;
    const double t = std::clamp(dot(p - TUBE_OUTER, ab) / dot(ab, ab), 0.0, 1.0);
    return distance(p, TUBE_OUTER + ab * t);
}

/// The point of the tube's axis nearest to p.
Vec3d nearestOnTubeAxis(const Vec3d& p)
{
    const Vec3d ab = TUBE_TIP - TUBE_OUTER;
    const double t = std::clamp(dot(p - TUBE_OUTER, ab) / dot(ab, ab), 0.0, 1.0);
    return TUBE_OUTER + ab * t;
}

/// Where the colon's air surrounds the tube beyond its wall (its axis deeper in the colon
/// than the wall's radius and a few mm), the tube is given to the lumen (rectal_tube.h, 5).
bool tubeSurrounded(const Vec3d& local)
{
    return test::featureDistanceMm(colon(), nearestOnTubeAxis(local)) < -(TUBE_WALL_RADIUS + 3.0);
}

/// The truth lumen: the colon's air, not the tube's (its wall and lumen) except where the
/// colon's air surrounds the tube.
bool truthLumen(const Vec3d& local, bool withTube)
{
    return test::featureDistanceMm(colon(), local) < 0 &&
           (!withTube || distanceToTubeAxis(local) > TUBE_WALL_RADIUS || tubeSurrounded(local));
}

/// Deep in the tube's lumen, more than one outer radius from the tip, outside the colon.
bool deepInTube(const Vec3d& local)
{
    return distanceToTubeAxis(local) < TUBE_LUMEN_RADIUS - 0.5 && distance(local, TUBE_TIP) > TUBE_WALL_RADIUS &&
           test::featureDistanceMm(colon(), local) > 0;
}

/// On the tube's axis well inside the rectum (axis deeper than the wall's radius + 4 mm).
bool tubeAxisInRectum(const Vec3d& local)
{
    return distanceToTubeAxis(local) < 1.0 && local.z < TUBE_TIP.z - 2.0 &&
           test::featureDistanceMm(colon(), nearestOnTubeAxis(local)) < -(TUBE_WALL_RADIUS + 4.0);
}

struct Overlap {
    double dice = 0;
    std::size_t tubeVoxelsInLumen = 0, tubeVoxels = 0;
    std::size_t tubeInRectumInLumen = 0, tubeInRectum = 0;  ///< the filled tube inside the rectum
    std::ostringstream notFilled;                             ///< local mm of those not in the lumen
};

/// Compares the lumen mask with the truth over local lattice points (local mm = index * 1 mm
/// of `toWorld`'s lattice).
template <typename ToWorld>
Overlap overlap(const LumenSegmentation& seg, bool withTube, const std::array<int, 3>& lo,
                const std::array<int, 3>& hi, ToWorld&& toWorld)
{
    const auto acc = seg.mask->getConstAccessor();
    const auto& xf = seg.mask->transform();
    std::size_t both = 0, truth = 0, mine = 0;
    Overlap o;
    for (int k = lo[2]; k <= hi[2]; ++k)
        for (int j = lo[1]; j <= hi[1]; ++j)
            for (int i = lo[0]; i <= hi[0]; ++i) {
                const Vec3d local{double(i), double(j), double(k)};
                const Vec3d w = toWorld(local);
                const bool in = acc.isValueOn(openvdb::Coord::round(xf.worldToIndex(openvdb::Vec3d(w.x, w.y, w.z))));
                const bool t = truthLumen(local, withTube);
                both += in && t;
                truth += t;
                mine += in;
                if (deepInTube(local) && local.z >= 0) {
                    ++o.tubeVoxels;
                    o.tubeVoxelsInLumen += in;
                }
                if (withTube && tubeAxisInRectum(local)) {
                    ++o.tubeInRectum;
                    o.tubeInRectumInLumen += in;
                    if (!in) o.notFilled << " (" << local.x << ", " << local.y << ", " << local.z << ")";
                }
            }
    o.dice = 2.0 * double(both) / double(truth + mine);
    return o;
}

std::string describeTube(const RectalTube& t, const std::function<Vec3d(const Vec3d&)>& local)
{
    std::ostringstream s;
    s << "tube: found " << t.found << ", tip (local) " << local(t.tipMm).x << "," << local(t.tipMm).y << ","
      << local(t.tipMm).z << ", entry " << local(t.entryMm).x << "," << local(t.entryMm).y << "," << local(t.entryMm).z
      << ", length " << t.lengthMm << " mm, diameter " << t.diameterMm << " mm, " << t.volumeMl << " mL";
    return s.str();
}

TEST(RectalTube, CtTubeIsCutFromTheLumenAndTheRectumKept)
{
    const HuPhantom ph = phantom(true);
    const auto hu = test::makeHuGrid(ph);
    LumenSegmentation seg;
    // Without the tube cut the colon touches the outside and is dropped: segmentation fails.
    ASSERT_NO_THROW(seg = segmentLumen(*hu, SegmentParams{})) << ph.describe();
    auto local = [&](const Vec3d& w) { return ph.frame.localFromWorld(w); };
    const RectalTube& t = seg.rectalTube;
    SCOPED_TRACE(describeTube(t, local));
    ASSERT_TRUE(t.found);
    EXPECT_LT(distance(local(t.tipMm), TUBE_TIP), 5.0);
    EXPECT_LT(distance(local(t.entryMm), truthEntry()), 5.0);
    EXPECT_NEAR(t.lengthMm, distance(truthEntry(), TUBE_TIP), 6.0);
    EXPECT_GT(t.diameterMm, 4.0);
    EXPECT_LT(t.diameterMm, 2 * TUBE_LUMEN_RADIUS + 1.0);

    int tubes = 0, kept = 0;
    for (const AirComponent& c : seg.components) {
        tubes += c.reason == "rectal tube";
        kept += c.kept;
        if (c.reason == "rectal tube") {
            EXPECT_FALSE(c.kept);
        }
    }
    EXPECT_EQ(tubes, 1);
    EXPECT_EQ(kept, 1);

    const Overlap o = overlap(seg, true, {0, 0, 0}, {99, 99, 179}, [&](const Vec3d& l) { return ph.frame.worldFromLocal(l); });
    EXPECT_GE(o.dice, 0.98);
    ASSERT_GT(o.tubeVoxels, 300u);
    EXPECT_EQ(o.tubeVoxelsInLumen, 0u) << "of " << o.tubeVoxels << " voxels deep in the tube's lumen";
    // Inside the rectum the tube is filled: the rectum's lumen has no rod in it.
    ASSERT_GT(o.tubeInRectum, 10u);
    EXPECT_EQ(o.tubeInRectumInLumen, o.tubeInRectum) << "voxels of the tube's axis inside the rectum in the lumen; not:" << o.notFilled.str();
    EXPECT_GT(t.filledMl, 0.5);

    // The tip is handed to the centerline stage in the level set's metadata.
    const auto meta = seg.sdf->getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META);
    ASSERT_TRUE(meta);
    EXPECT_LT(distance(Vec3d{meta->value()[0], meta->value()[1], meta->value()[2]}, t.tipMm), 1e-9);
}

TEST(RectalTube, NoTubeNoneReported)
{
    // The same colon without a tube, plus air reaching through the body surface beside it.
    HuPhantom ph = phantom(false);
    ph.features.push_back({"outside", Axis::straight({85, 80, 40}, {130, 80, 40}), 5.0, -1000});
    const auto hu = test::makeHuGrid(ph);
    const LumenSegmentation seg = segmentLumen(*hu, SegmentParams{});
    EXPECT_FALSE(seg.rectalTube.found);
    EXPECT_FALSE(seg.sdf->getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META));
    const Overlap o = overlap(seg, false, {0, 0, 0}, {99, 99, 179}, [&](const Vec3d& l) { return ph.frame.worldFromLocal(l); });
    EXPECT_GE(o.dice, 0.98);
}

// ------------------------------------------------------------------ masks

/// A slightly oblique 1 mm lattice whose index * 1 mm is the local frame above, starting at
/// local z = z0 (the image holds z0 .. 179).
ImageGeometry maskGeometry(int z0)
{
    ImageGeometry g;
    g.size = {100, 100, 180 - z0};
    g.spacingMm = {1, 1, 1};
    const double b = 0.15;  // a tilt about x
    g.direction = Mat3d{{{1, 0, 0}, {0, std::cos(b), -std::sin(b)}, {0, std::sin(b), std::cos(b)}}};
    g.originMm = {-20.0, 7.5, -300.0};
    g.originMm = g.worldFromIndex({0, 0, double(z0)});  // voxel (0,0,0) at local z = z0
    return g;
}

enum class MaskKind {
    Threshold,  ///< the air: the tube's wall is a hole in the rectum, its lumen is labelled
    Filled      ///< the rectum filled (tube included), the tube's lumen labelled outside it
};

Image3<float> tubeMask(MaskKind kind, int z0, bool withTube)
{
    Image3<float> img;
    img.geometry = maskGeometry(z0);
    const ImageGeometry& g = img.geometry;
    img.voxels.assign(std::size_t(g.voxelCount()), 0.0f);
    const HuFeature c = colon(), lumen = tubeLumen();
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                const Vec3d l{double(i), double(j), double(k + z0)};
                const bool inColon = test::featureDistanceMm(c, l) < 0;
                const bool inLumen = withTube && test::featureDistanceMm(lumen, l) < 0;
                const bool inWall = withTube && distanceToTubeAxis(l) <= TUBE_WALL_RADIUS;
                bool on = false;
                if (kind == MaskKind::Threshold) on = inLumen || (inColon && !inWall);
                else on = inColon || inLumen;
                if (on) img.at(i, j, k) = 1.0f;
            }
    return img;
}

Vec3d localOfMask(const ImageGeometry& g, int z0, const Vec3d& w)
{
    const Vec3d u = g.indexFromWorld(w);
    return {u.x, u.y, u.z + z0};
}

TEST(RectalTube, ThresholdMaskTubeCutWithItsTip)
{
    const int z0 = 0;  // the tube leaves through the image's bottom face
    const Image3<float> img = tubeMask(MaskKind::Threshold, z0, true);
    const LumenSegmentation seg = segmentFromMask(img, SegmentParams{});
    auto local = [&](const Vec3d& w) { return localOfMask(img.geometry, z0, w); };
    const RectalTube& t = seg.rectalTube;
    SCOPED_TRACE(describeTube(t, local));
    ASSERT_TRUE(t.found);
    EXPECT_LT(distance(local(t.tipMm), TUBE_TIP), 5.0);
    EXPECT_LT(distance(local(t.entryMm), truthEntry()), 5.0);
    const Overlap o = overlap(seg, true, {0, 0, z0}, {99, 99, 179}, [&](const Vec3d& l) {
        return img.geometry.worldFromIndex({l.x, l.y, l.z - z0});
    });
    EXPECT_GE(o.dice, 0.98);
    ASSERT_GT(o.tubeVoxels, 300u);
    EXPECT_EQ(o.tubeVoxelsInLumen, 0u) << "of " << o.tubeVoxels << " voxels deep in the tube's lumen";
    ASSERT_GT(o.tubeInRectum, 10u);
    EXPECT_EQ(o.tubeInRectumInLumen, o.tubeInRectum) << "voxels of the tube's axis inside the rectum in the lumen; not:" << o.notFilled.str();
}

TEST(RectalTube, FilledMaskTubeBelowTheRectumCutRectumKept)
{
    // The tube ends inside the image (its outer end is the mask's lowest point); inside the
    // rectum the mask cannot show it, so the tip is where it enters the rectum.
    const int z0 = -30;
    const Image3<float> img = tubeMask(MaskKind::Filled, z0, true);
    const LumenSegmentation seg = segmentFromMask(img, SegmentParams{});
    auto local = [&](const Vec3d& w) { return localOfMask(img.geometry, z0, w); };
    const RectalTube& t = seg.rectalTube;
    SCOPED_TRACE(describeTube(t, local));
    ASSERT_TRUE(t.found);
    // Where the axis enters the colon.
    Vec3d enters = TUBE_OUTER;
    for (double s = 0; s <= 1; s += 0.001) {
        enters = TUBE_OUTER + (TUBE_TIP - TUBE_OUTER) * s;
        if (test::featureDistanceMm(colon(), enters) < 0) break;
    }
    EXPECT_LT(distance(local(t.tipMm), enters), 6.0);
    EXPECT_LT(local(t.outerEndMm).z, TUBE_OUTER.z + 5.0);
    // Only the colon remains: Dice against the colon itself.
    const auto acc = seg.mask->getConstAccessor();
    const auto& xf = seg.mask->transform();
    std::size_t both = 0, truth = 0, mine = 0, tubeOutside = 0, tubeOutsideInLumen = 0;
    for (int k = z0; k <= 179; ++k)
        for (int j = 0; j <= 99; ++j)
            for (int i = 0; i <= 99; ++i) {
                const Vec3d l{double(i), double(j), double(k)};
                const Vec3d w = img.geometry.worldFromIndex({l.x, l.y, l.z - z0});
                const bool in = acc.isValueOn(openvdb::Coord::round(xf.worldToIndex(openvdb::Vec3d(w.x, w.y, w.z))));
                const bool tr = test::featureDistanceMm(colon(), l) < 0;
                both += in && tr;
                truth += tr;
                mine += in;
                if (distanceToTubeAxis(l) < TUBE_LUMEN_RADIUS - 0.5 && test::featureDistanceMm(colon(), l) > TUBE_WALL_RADIUS) {
                    ++tubeOutside;
                    tubeOutsideInLumen += in;
                }
            }
    EXPECT_GE(2.0 * double(both) / double(truth + mine), 0.98);
    ASSERT_GT(tubeOutside, 300u);
    EXPECT_EQ(tubeOutsideInLumen, 0u) << "of " << tubeOutside << " voxels of the tube below the rectum";
}

TEST(RectalTube, MasksWithoutTubeNoneReported)
{
    for (const int z0 : {0, -30}) {
        const Image3<float> img = tubeMask(MaskKind::Filled, z0, false);
        const LumenSegmentation seg = segmentFromMask(img, SegmentParams{});
        EXPECT_FALSE(seg.rectalTube.found) << "z0 " << z0;
    }
}

// ------------------------------------------------------------------ plausible colons

Image3<float> ballsMask(const std::vector<std::pair<Vec3d, double>>& balls)
{
    Image3<float> img;
    img.geometry = maskGeometry(0);
    img.voxels.assign(std::size_t(img.geometry.voxelCount()), 0.0f);
    for (int64_t k = 0; k < img.geometry.size[2]; ++k)
        for (int64_t j = 0; j < img.geometry.size[1]; ++j)
            for (int64_t i = 0; i < img.geometry.size[0]; ++i)
                for (const auto& [c, r] : balls)
                    if (distance(Vec3d{double(i), double(j), double(k)}, c) < r) img.at(i, j, k) = 3.0f;
    return img;
}

TEST(RectalTube, MasksWithoutPlausibleColonRefused)
{
    SegmentParams p;
    auto message = [&](const Image3<float>& img) {
        try {
            checkPlausibleColon(segmentFromMask(img, p), p, "test mask");
        } catch (const InputError& e) {
            return std::string(e.what());
        }
        return std::string("no error");
    };
    // One ball of 65 mL.
    std::string m = message(ballsMask({{{50, 50, 90}, 25}}));
    EXPECT_NE(m.find("no plausible colon"), std::string::npos) << m;
    EXPECT_NE(m.find("compact"), std::string::npos) << m;
    EXPECT_EQ(m.find('\n'), std::string::npos) << m;
    // Small pieces only (about 4 mL each).
    m = message(ballsMask({{{30, 30, 40}, 10}, {{70, 70, 90}, 10}, {{30, 70, 140}, 10}}));
    EXPECT_NE(m.find("no plausible colon"), std::string::npos) << m;
    EXPECT_NE(m.find("3 piece(s)"), std::string::npos) << m;
    // The U-shaped colon passes.
    EXPECT_NO_THROW(checkPlausibleColon(segmentFromMask(tubeMask(MaskKind::Filled, 0, false), p), p, "test mask"));
}

} // namespace
} // namespace flyover
