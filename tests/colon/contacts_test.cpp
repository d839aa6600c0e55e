// Contacts between touching loops (colon/contacts.h) on analytic tubes joined through thin
// necks, and the centerline through the cut lumen: every neck found and cut, the path follows
// the tube's own axis (no shortcut), starts at the lower end; narrow places that close no
// cycle (a collapsed stretch, beads) are never cut.
#include "colon/contacts.h"
#include "volume/vec3.h"

#include "tests/shapes/test_shapes.h"
#include "colon/centerline.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <string>
#include <vector>

namespace flyover {
namespace {

using test::Axis;
using test::Frame;

/// a = min(a, b) on b's active voxels (a union of two sdfs on the same frame that keeps every
/// interior voxel active, as the centerline expects; openvdb's csgUnion prunes the interior).
void unionInto(openvdb::FloatGrid& a, const openvdb::FloatGrid& b)
{
    auto acc = a.getAccessor();
    for (auto it = b.cbeginValueOn(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        if (!acc.isValueOn(c) || *it < acc.getValue(c)) acc.setValueOn(c, *it);
    }
}

/// A tube with thin necks to other parts of itself (each a capsule between two axis points).
struct Touching {
    std::string name;
    Frame frame;
    Axis axis;
    double radiusMm;
    std::vector<std::pair<Vec3d, Vec3d>> necks;  ///< local mm, on the axis
    double neckRadiusMm;

    openvdb::FloatGrid::Ptr sdf() const
    {
        auto g = test::makeTubeSdf(frame, axis, radiusMm);
        for (const auto& [a, b] : necks) unionInto(*g, *test::makeTubeSdf(frame, Axis::straight(a, b), neckRadiusMm));
        return g;
    }
    std::string describe() const
    {
        return name + ": " + axis.describe() + ", radius " + std::to_string(radiusMm) + " mm, " +
               std::to_string(necks.size()) + " necks of radius " + std::to_string(neckRadiusMm) +
               " mm, " + frame.describe();
    }
};

/// U-bend whose legs (5 mm of wall gap) are joined by one neck halfway up.
Touching uWithNeck(bool rotated, double voxelMm)
{
    const Axis axis = Axis::uBend({20, 20, 15}, 70, 70, 8.5);
    return {"uWithNeck", test::makeFrame(voxelMm, rotated), axis, 6.0, {{{20, 20, 50}, {37, 20, 50}}}, 1.5};
}

/// Two turns of a helix (turns 13.8 mm apart, walls 2.8 mm apart) joined by three necks.
Touching helixWithNecks(bool rotated, double voxelMm)
{
    const double R = 20, c = 2.2;
    const Vec3d center{40, 40, 12};
    const Axis axis = Axis::helix(center, R, c, 2.0);
    auto at = [&](double t) { return center + Vec3d{R * std::cos(t), R * std::sin(t), c * t}; };
    Touching t{"helixWithNecks", test::makeFrame(voxelMm, rotated), axis, 5.5, {}, 1.2};
    for (double a : {1.0, 3.2, 5.0}) t.necks.push_back({at(a), at(a + 2 * PI)});
    return t;
}

/// The checks of a path against its tube's axis: start at the lower end (or rectumMm), mean
/// and p95 distance to the axis, length, no jump along the axis, no sharp turn.
void checkPath(const Centerline& cl, const Touching& tc, const Vec3d& rectumLocal)
{
    ASSERT_GE(cl.points.size(), 10u);
    const double L = tc.axis.lengthMm();
    std::vector<double> err;
    double prevArc = -1, worstJump = 0;
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        const auto proj = tc.axis.project(tc.frame.localFromWorld(cl.points[i].positionMm));
        err.push_back(proj.distanceMm);
        if (i > 0) worstJump = std::max(worstJump, std::abs(proj.arcMm - prevArc));
        prevArc = proj.arcMm;
    }
    std::vector<double> sorted(err);
    std::sort(sorted.begin(), sorted.end());
    double mean = 0;
    for (double e : err) mean += e / double(err.size());
    const double p95 = sorted[std::size_t(0.95 * double(sorted.size() - 1))];
    const Vec3d first = tc.frame.localFromWorld(cl.points.front().positionMm);
    const double firstArc = tc.axis.project(first).arcMm;
    const double lastArc = tc.axis.project(tc.frame.localFromWorld(cl.points.back().positionMm)).arcMm;
    const double trueLength = std::abs(lastArc - firstArc);
    double sharpest = 0;
    for (std::size_t i = 1; i + 1 < cl.points.size(); ++i) {
        const Vec3d a = cl.points[i].positionMm - cl.points[i - 1].positionMm;
        const Vec3d b = cl.points[i + 1].positionMm - cl.points[i].positionMm;
        sharpest = std::max(sharpest, std::acos(std::clamp(dot(normalize(a), normalize(b)), -1.0, 1.0)) * 180 / PI);
    }
    std::cout << "[ " << tc.name << " ] " << cl.points.size() << " points, length " << cl.lengthMm()
              << " mm vs axis " << L << " mm; error to axis mean " << mean << " p95 " << p95
              << " mm; largest jump along the axis " << worstJump << " mm; sharpest turn " << sharpest
              << " deg per " << cl.stepMm << " mm\n";
    EXPECT_LE(mean, 1.0) << "mean distance of the path to the tube's axis (mm)";
    EXPECT_LE(p95, 2.0) << "p95 distance of the path to the tube's axis (mm)";
    EXPECT_LT(distance(first, rectumLocal), tc.radiusMm) << "the path starts at the rectum end";
    EXPECT_NEAR(cl.lengthMm(), L, 0.03 * L) << "path length vs the tube's axis";
    EXPECT_NEAR(trueLength, L, 2 * tc.radiusMm) << "axis span of the path";
    EXPECT_LE(worstJump, 3.0 * cl.stepMm) << "consecutive points jump along the axis: a shortcut";
    EXPECT_LT(sharpest, 30.0) << "turn between consecutive steps (deg)";
}

/// Every neck found and cut within a few mm; nothing else cut.
void checkContacts(const ContactReport& r, const Touching& tc)
{
    std::size_t cut = 0;
    for (const ContactInfo& c : r.contacts) {
        std::cout << "    contact at " << c.positionMm.x << ", " << c.positionMm.y << ", "
                  << c.positionMm.z << " width " << c.widthMm << " sides " << c.sideRadiusMm[0]
                  << "/" << c.sideRadiusMm[1] << " straight " << c.straightMm << " detour "
                  << c.detourMm << " removed " << c.voxelsRemoved << (c.cut ? " cut" : " kept") << "\n";
        cut += c.cut;
    }
    EXPECT_EQ(cut, tc.necks.size()) << "contacts cut vs necks";
    for (const auto& [a, b] : tc.necks) {
        double best = 1e9;
        for (const ContactInfo& c : r.contacts) {
            if (!c.cut) continue;
            const Vec3d p = tc.frame.localFromWorld(c.positionMm);
            // Distance to the neck's segment.
            const Vec3d ab = b - a;
            const double t = std::clamp(dot(p - a, ab) / dot(ab, ab), 0.0, 1.0);
            best = std::min(best, distance(p, a + ab * t));
        }
        EXPECT_LT(best, 3.0) << "a contact on the neck from " << a.x << "," << a.y << "," << a.z;
    }
    for (const ContactInfo& c : r.contacts)
        if (c.cut) {
            EXPECT_LT(c.widthMm, 2 * tc.neckRadiusMm + 2 * tc.frame.voxelMm);
            EXPECT_GT(c.voxelsRemoved, 0u);
        }
    EXPECT_EQ(r.pieces, 1u);
}

TEST(Contacts, UBendWithNeckIsCutAndPathFollowsTheU)
{
    for (bool rotated : {false, true}) {
        const Touching tc = uWithNeck(rotated, 0.75);
        SCOPED_TRACE(tc.describe());
        auto sdf = tc.sdf();
        // Without the cut the cheapest path between the leg ends takes the neck.
        const ContactReport r = cutContacts(*sdf, nullptr, ContactParams{});
        checkContacts(r, tc);
        CenterlineParams params;
        params.rectumMm = tc.frame.worldFromLocal(tc.axis.start() - Vec3d{0, 0, 8});
        CenterlineReport cr;
        const Centerline cl = extractCenterline(*sdf, params, nullptr, &cr);
        checkPath(cl, tc, tc.axis.start());
        EXPECT_TRUE(cr.bridges.empty());
    }
}

TEST(Contacts, HelixWithThreeNecksIsCutAtEveryNeck)
{
    const Touching tc = helixWithNecks(true, 0.75);
    SCOPED_TRACE(tc.describe());
    auto sdf = tc.sdf();
    const ContactReport r = cutContacts(*sdf, nullptr, ContactParams{});
    checkContacts(r, tc);
    CenterlineParams params;
    params.rectumMm = tc.frame.worldFromLocal(tc.axis.start());
    const Centerline cl = extractCenterline(*sdf, params);
    checkPath(cl, tc, tc.axis.start());
}

TEST(Contacts, SameCutsOnAnyNumberOfThreads)
{
    // The ways round before the first cut run side by side when more than one thread may (the
    // flood's batches too, on lumens larger than these: ContactRegions.* covers them): the
    // report and the cut grids must be those of one thread.
    for (const Touching& tc : {helixWithNecks(true, 0.75), uWithNeck(true, 0.75)}) {
        SCOPED_TRACE(tc.describe());
        ContactReport expected;
        openvdb::FloatGrid::Ptr expectedSdf;
        for (int threads : {1, 2, 4}) {
            auto sdf = tc.sdf();
            ContactReport r;
            tbb::task_arena arena(threads);
            arena.execute([&] { r = cutContacts(*sdf, nullptr, ContactParams{}); });
            if (threads == 1) {
                ASSERT_FALSE(r.contacts.empty()) << "expected cut contacts";
                expected = r;
                expectedSdf = sdf;
                continue;
            }
            EXPECT_EQ(r.regions, expected.regions) << threads << " threads: regions";
            EXPECT_EQ(r.links, expected.links) << threads << " threads: links";
            EXPECT_EQ(r.cycleLinks, expected.cycleLinks) << threads << " threads: cycle links";
            EXPECT_EQ(r.wideCycles, expected.wideCycles) << threads << " threads: wide cycles";
            ASSERT_EQ(r.contacts.size(), expected.contacts.size()) << threads << " threads: contacts";
            for (std::size_t i = 0; i < r.contacts.size(); ++i) {
                const ContactInfo &a = r.contacts[i], &b = expected.contacts[i];
                EXPECT_EQ(a.cut, b.cut) << threads << " threads, contact " << i;
                EXPECT_EQ(a.positionMm.x, b.positionMm.x) << threads << " threads, contact " << i;
                EXPECT_EQ(a.positionMm.y, b.positionMm.y) << threads << " threads, contact " << i;
                EXPECT_EQ(a.positionMm.z, b.positionMm.z) << threads << " threads, contact " << i;
                EXPECT_EQ(a.widthMm, b.widthMm) << threads << " threads, contact " << i;
                EXPECT_EQ(a.voxelsRemoved, b.voxelsRemoved) << threads << " threads, contact " << i;
                EXPECT_EQ(a.links, b.links) << threads << " threads, contact " << i;
            }
            std::size_t differ = 0, active = 0;
            auto acc = expectedSdf->getConstAccessor();
            for (auto it = sdf->cbeginValueOn(); it; ++it, ++active) {
                float v;
                if (!acc.probeValue(it.getCoord(), v) || v != *it) ++differ;
            }
            EXPECT_EQ(active, expectedSdf->activeVoxelCount()) << threads << " threads: active voxels";
            EXPECT_EQ(differ, 0u) << threads << " threads: sdf voxels that differ from one thread's cut";
        }
    }
}

TEST(Contacts, LowestEndIsTheRectumWithoutHint)
{
    // Unrotated: the helix starts at its lowest point (local z = world z up to a translation).
    const Touching tc = helixWithNecks(false, 0.75);
    SCOPED_TRACE(tc.describe());
    auto sdf = tc.sdf();
    cutContacts(*sdf, nullptr, ContactParams{});
    const Centerline cl = extractCenterline(*sdf, CenterlineParams{});
    checkPath(cl, tc, tc.axis.start());
}

TEST(Contacts, WithoutTheCutThePathTakesTheShortcut)
{
    // The test above would pass without this module only if the centerline avoided necks by
    // itself: it does not (the minimal path between the farthest ends uses the neck).
    const Touching tc = uWithNeck(false, 0.75);
    auto sdf = tc.sdf();
    CenterlineParams params;
    params.rectumMm = tc.frame.worldFromLocal(tc.axis.start() - Vec3d{0, 0, 8});
    const Centerline cl = extractCenterline(*sdf, params);
    EXPECT_LT(cl.lengthMm(), 0.8 * tc.axis.lengthMm()) << "expected the uncut path to take the neck";
}

TEST(Contacts, MaskIsCutWithTheSdf)
{
    const Touching tc = uWithNeck(true, 0.75);
    auto sdf = tc.sdf();
    auto mask = openvdb::BoolGrid::create(false);
    mask->setTransform(sdf->transform().copy());
    for (auto it = sdf->cbeginValueOn(); it; ++it)
        if (*it < 0) mask->tree().setValueOn(it.getCoord(), true);
    const openvdb::Index64 before = mask->activeVoxelCount();
    const ContactReport r = cutContacts(*sdf, mask.get(), ContactParams{});
    ASSERT_EQ(r.contacts.size(), 1u);
    EXPECT_EQ(before - mask->activeVoxelCount(), r.contacts[0].voxelsRemoved);
    for (auto it = mask->cbeginValueOn(); it; ++it)
        EXPECT_LT(sdf->tree().getValue(it.getCoord()), 0.0f) << it.getCoord();
}

TEST(Contacts, NarrowPlacesWithoutCycleAreNeverCut)
{
    const Frame frame = test::makeFrame(0.75, true);
    // A collapsed stretch that continues the tube: two wide stretches joined by 20 mm of a
    // 0.8 mm thread (the path passes it closer than 1 mm to the wall: reported).
    auto collapsed = test::makeTubeSdf(frame, Axis::straight({20, 20, 10}, {20, 20, 50}), 6.0);
    unionInto(*collapsed, *test::makeTubeSdf(frame, Axis::straight({20, 20, 50}, {20, 20, 70}), 0.8));
    unionInto(*collapsed, *test::makeTubeSdf(frame, Axis::straight({20, 20, 70}, {20, 20, 110}), 6.0));
    // Beads: spheres 10 mm apart of radius 6 (necks of 3.3 mm radius, like haustral folds).
    auto beads = test::makeTubeSdf(frame, Axis::sphere({20, 20, 10}), 6.0);
    for (int k = 1; k < 10; ++k) unionInto(*beads, *test::makeTubeSdf(frame, Axis::sphere({20, 20, 10 + 10.0 * k}), 6.0));
    // Plain U-bend and helix.
    auto u = test::makeTubeSdf(frame, Axis::uBend({20, 30, 20}, 40, 55, 15), 6.0);
    auto helix = test::makeTubeSdf(frame, Axis::helix({40, 40, 15}, 20, 8, 1.5), 6.0);
    for (auto [name, grid] : {std::pair<const char*, openvdb::FloatGrid::Ptr>{"collapsed", collapsed},
                              {"beads", beads}, {"uBend", u}, {"helix", helix}}) {
        SCOPED_TRACE(name);
        const openvdb::Index64 before = grid->activeVoxelCount();
        const ContactReport r = cutContacts(*grid, nullptr, ContactParams{});
        EXPECT_TRUE(r.contacts.empty()) << r.contacts.size() << " contacts, first at "
                                        << (r.contacts.empty() ? 0.0 : r.contacts[0].positionMm.z);
        EXPECT_EQ(r.pieces, 1u);
        EXPECT_EQ(grid->activeVoxelCount(), before);
    }
    CenterlineReport cr;
    const Centerline cl = extractCenterline(*collapsed, CenterlineParams{}, nullptr, &cr);
    EXPECT_NEAR(cl.lengthMm(), 100.0, 12.0);
    ASSERT_FALSE(cr.nearWall.empty()) << "the 0.8 mm thread is closer than 1 mm to the wall";
    // The thread runs from local z 50 to 70: arcs ~40..60 from the lower end (capped ends cut
    // a few mm off).
    EXPECT_GT(cr.nearWall.front().fromArcMm, 25.0);
    EXPECT_LT(cr.nearWall.back().toArcMm, 75.0);
    EXPECT_LT(cr.nearWall.front().minRadiusMm, 1.0);
}

TEST(Contacts, TubesJoinedFromTheSideWithoutACycleAreCut)
{
    // Two separate tubes (a collapse elsewhere keeps them apart along the colon) side by side,
    // walls 3 mm apart, joined by one neck: no cycle, but the neck meets each tube from the
    // side (60 mm of tube on either hand): a contact, cut, and the lumen is two pieces again.
    const Frame frame = test::makeFrame(0.75, true);
    auto grid = test::makeTubeSdf(frame, Axis::straight({20, 20, 10}, {20, 20, 130}), 6.0);
    unionInto(*grid, *test::makeTubeSdf(frame, Axis::straight({35, 20, 10}, {35, 20, 130}), 6.0));
    unionInto(*grid, *test::makeTubeSdf(frame, Axis::straight({20, 20, 70}, {35, 20, 70}), 1.2));
    const ContactReport r = cutContacts(*grid, nullptr, ContactParams{});
    EXPECT_EQ(r.pieces, 1u);
    ASSERT_EQ(r.contacts.size(), 1u);
    EXPECT_TRUE(r.contacts[0].cut) << r.contacts[0].reason;
    const Vec3d at = frame.localFromWorld(r.contacts[0].positionMm);
    EXPECT_NEAR(at.x, 27.5, 4.0);
    EXPECT_NEAR(at.z, 70.0, 3.0);
    EXPECT_LT(r.contacts[0].widthMm, 3.0);
    const ContactReport after = cutContacts(*grid, nullptr, ContactParams{});
    EXPECT_EQ(after.pieces, 2u) << "the two tubes are apart after the cut";
    EXPECT_TRUE(after.contacts.empty());

    // The end of one tube joined to the side of the other (a T): the neck continues a tube on
    // one hand, as a collapse or a stricture does: not cut.
    auto tee = test::makeTubeSdf(frame, Axis::straight({20, 20, 10}, {20, 20, 130}), 6.0);
    unionInto(*tee, *test::makeTubeSdf(frame, Axis::straight({35, 20, 70}, {95, 20, 70}), 6.0));
    unionInto(*tee, *test::makeTubeSdf(frame, Axis::straight({20, 20, 70}, {35, 20, 70}), 1.2));
    const openvdb::Index64 before = tee->activeVoxelCount();
    const ContactReport t = cutContacts(*tee, nullptr, ContactParams{});
    EXPECT_TRUE(t.contacts.empty()) << t.contacts.size() << " contacts";
    EXPECT_EQ(tee->activeVoxelCount(), before);
}

TEST(Contacts, DisabledOrBadParameters)
{
    const Touching tc = uWithNeck(false, 0.75);
    auto sdf = tc.sdf();
    ContactParams off;
    off.enabled = false;
    EXPECT_TRUE(cutContacts(*sdf, nullptr, off).contacts.empty());
    for (auto set : std::vector<void (*)(ContactParams&)>{
             [](ContactParams& p) { p.maxNeckRatio = 0; }, [](ContactParams& p) { p.maxNeckRatio = 1.5; },
             [](ContactParams& p) { p.minDetourRatio = std::nan(""); },
             [](ContactParams& p) { p.chunkMm = -1; }, [](ContactParams& p) { p.minDetourMm = -1; },
             [](ContactParams& p) { p.minArmMm = -1; }, [](ContactParams& p) { p.minArmRadii = std::nan(""); }}) {
        ContactParams bad;
        set(bad);
        EXPECT_THROW(cutContacts(*sdf, nullptr, bad), ParameterError);
    }
}

} // namespace
} // namespace flyover
