// Tests of the harder phantom variants (colon/phantom.h): loops touching through a narrow
// contact, the redundant colon, the rectal tube, anisotropic voxels, and all of them together;
// checked on the voxels of the small size (2.5 mm) and on the truth JSON's round trip.
#include "colon/phantom.h"
#include "colon/phantom_anatomy.h"
#include "colon/phantom_io.h"
#include "tests/colon/truth_arc.h"
#include "tests/shapes/test_shapes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace flyover;
namespace ph = flyover::phantom;
using test::nearestArcMm;

constexpr double VARIANT_NOISE_HU = 15.0;

std::string describe(const PhantomParams& p)
{
    std::ostringstream s;
    s << "phantom size=" << phantomSizeName(p.size) << " seed=" << p.seed << " touching=" << p.touching
      << (p.redundant ? " redundant" : "") << (p.rectalTube ? " rectal-tube" : "") << (p.fluid ? " fluid" : "")
      << (p.collapse ? " collapse" : "") << (p.stricture ? " stricture" : "") << " spacing=" << p.spacingMm.x << "," << p.spacingMm.y << ","
      << p.spacingMm.z;
    return s.str();
}

using Index = std::array<int64_t, 3>;

using test::nearestVoxel;

bool inside(const ImageGeometry& g, const Index& v)
{
    for (int c = 0; c < 3; ++c)
        if (v[std::size_t(c)] < 0 || v[std::size_t(c)] >= g.size[std::size_t(c)])
            return false;
    return true;
}

constexpr int FACE[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};

/// Face-connected flood fill from `start` over the voxels `pass` accepts; true when it reaches `goal`.
template <typename Pass>
bool faceConnected(const ImageGeometry& g, const Index& start, const Index& goal, Pass pass)
{
    if (!pass(start) || !pass(goal))
        return false;
    std::vector<uint8_t> seen(std::size_t(g.voxelCount()), 0);
    const auto lin = [&](const Index& v) { return std::size_t(v[0] + g.size[0] * (v[1] + g.size[1] * v[2])); };
    std::deque<Index> queue{start};
    seen[lin(start)] = 1;
    while (!queue.empty()) {
        const Index v = queue.front();
        queue.pop_front();
        if (v == goal)
            return true;
        for (const auto& f : FACE) {
            const Index w{v[0] + f[0], v[1] + f[1], v[2] + f[2]};
            if (!inside(g, w) || seen[lin(w)] || !pass(w))
                continue;
            seen[lin(w)] = 1;
            queue.push_back(w);
        }
    }
    return false;
}

/// The world axis (0, 1, 2) of a contact's channel.
int axisOf(const PhantomContact& c)
{
    int k = 0;
    for (int a = 1; a < 3; ++a)
        if (std::abs(c.axis[a]) > std::abs(c.axis[k]))
            k = a;
    return k;
}

/// Every contact: far apart along the colon, its arcs on the truth centerline next to it, the
/// truth mask face-connected through it within 25 mm of it, 1-3 voxels wide across it, and
/// both loops of their full radius beside it.
void expectContactsHold(const Phantom& phantom, const std::string& what)
{
    SCOPED_TRACE(what);
    const auto& g = phantom.truthLumen.geometry;
    const auto& t = phantom.truth;
    const auto mask = [&](const Index& v) { return phantom.truthLumen.at(v[0], v[1], v[2]) != 0; };
    for (std::size_t n = 0; n < t.contacts.size(); ++n) {
        const PhantomContact& c = t.contacts[n];
        SCOPED_TRACE("contact " + std::to_string(n) + " at arcs " + std::to_string(c.arcAMm) + " / " +
                     std::to_string(c.arcBMm) + " mm");
        EXPECT_GE(c.arcBMm - c.arcAMm, 150.0) << "the loops must be far apart along the colon";
        if (n > 0) {
            EXPECT_GE(c.arcAMm, t.contacts[n - 1].arcAMm) << "contacts sorted by arc_a";
        }
        // The position lies between the two loops, a wall thickness from each lumen.
        const auto ia = std::size_t(std::lround(c.arcAMm)), ib = std::size_t(std::lround(c.arcBMm));
        const double da = distance(t.centerlineMm[ia], c.positionMm) - t.radiusMm[ia];
        const double db = distance(t.centerlineMm[ib], c.positionMm) - t.radiusMm[ib];
        EXPECT_NEAR(da, ph::COLON_WALL_MM, 1.0) << "contact to lumen A (mm)";
        EXPECT_NEAR(db, ph::COLON_WALL_MM, 1.0) << "contact to lumen B (mm)";

        // Connected through the contact: from a voxel in lumen A to one in lumen B, inside a
        // 25 mm ball around the contact.
        // 12 mm inside each lumen, on the line between the loops' centres: clear of the
        // channel, which reaches a voxel or so into each lumen.
        const Vec3d toB = normalize(t.centerlineMm[ib] - t.centerlineMm[ia]);
        const Index inA = nearestVoxel(g, c.positionMm - toB * (ph::COLON_WALL_MM + 12.0));
        const Index inB = nearestVoxel(g, c.positionMm + toB * (ph::COLON_WALL_MM + 12.0));
        const auto nearContact = [&](const Index& v) {
            const Vec3d w = g.worldFromIndex({double(v[0]), double(v[1]), double(v[2])});
            return distance(w, c.positionMm) < 25.0 && mask(v);
        };
        EXPECT_TRUE(mask(inA)) << "a point 12 mm inside lumen A is not truth lumen";
        EXPECT_TRUE(mask(inB)) << "a point 12 mm inside lumen B is not truth lumen";
        EXPECT_TRUE(faceConnected(g, inA, inB, nearContact))
            << "truth lumen of loop A and loop B not face-connected within 25 mm of the contact";
        // ... and only through it: not connected when the contact's voxels are left out.
        const auto awayFromChannel = [&](const Index& v) {
            const Vec3d w = g.worldFromIndex({double(v[0]), double(v[1]), double(v[2])});
            return nearContact(v) && ph::contactSignedDistanceMm(c, w) > 0.0;
        };
        EXPECT_FALSE(faceConnected(g, inA, inB, awayFromChannel))
            << "loops A and B are connected near the contact but outside its channel";

        // 1-3 voxels wide: runs of truth lumen across the channel through its centre voxel.
        const Index centre = nearestVoxel(g, c.positionMm);
        EXPECT_TRUE(mask(centre)) << "the voxel at the contact's centre is not truth lumen";
        const int k = axisOf(c);
        for (int across : {(k + 1) % 3, (k + 2) % 3}) {
            int run = mask(centre) ? 1 : 0;
            for (int dir : {-1, 1})
                for (Index v = centre;;) {
                    v[std::size_t(across)] += dir;
                    if (!inside(g, v) || !mask(v)) break;
                    ++run;
                }
            EXPECT_GE(run, 1) << "channel width along axis " << across << " (voxels)";
            EXPECT_LE(run, 3) << "channel width along axis " << across << " (voxels)";
        }
        EXPECT_LE(c.widthMm, 3.0 * std::min({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z}) + 1e-9);

        // Full radius beside the contact: across each loop, perpendicular to its tangent and to
        // the direction of the other loop, the lumen spans the truth radius (within a voxel).
        const double h = std::max({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z});
        for (std::size_t i : {ia, ib}) {
            const std::size_t lo = i > 0 ? i - 1 : i, hi = std::min(i + 1, t.centerlineMm.size() - 1);
            const Vec3d tangent = normalize(t.centerlineMm[hi] - t.centerlineMm[lo]);
            const Vec3d side = normalize(cross(tangent, toB));
            for (double sign : {-1.0, 1.0}) {
                const Vec3d in = t.centerlineMm[i] + side * (sign * (t.radiusMm[i] - 1.5 * h));
                const Vec3d out = t.centerlineMm[i] + side * (sign * (t.radiusMm[i] + 1.5 * h));
                EXPECT_TRUE(mask(nearestVoxel(g, in))) << "lumen narrower than its radius beside arc " << i;
                EXPECT_FALSE(mask(nearestVoxel(g, out))) << "lumen wider than its radius beside arc " << i;
            }
        }
    }
}

/// Arc (mm) of the truth centerline sample whose tube surface is nearest to p (least
/// distance - radius): unlike the nearest centerline point, this does not put a voxel of a
/// wide loop into a narrow one pressed against it.
double nearestTubeArcMm(const PhantomTruth& t, const Vec3d& p)
{
    const auto sd = [&](std::size_t i) { return distance(t.centerlineMm[i], p) - t.radiusMm[i]; };
    const std::size_t n = t.centerlineMm.size();
    std::size_t best = 0;
    for (std::size_t i = 0; i < n; i += 8)
        if (sd(i) < sd(best)) best = i;
    const std::size_t lo = best >= 8 ? best - 8 : 0, hi = std::min(n - 1, best + 8);
    for (std::size_t i = lo; i <= hi; ++i)
        if (sd(i) < sd(best)) best = i;
    return double(best);
}

/// Face-adjacent truth lumen voxels whose nearest centerline points are non-adjacent parts of
/// the colon (> 100 mm of arc apart) and that lie farther than 20 mm from every contact.
int64_t undeclaredTouches(const Phantom& phantom)
{
    const auto& g = phantom.truthLumen.geometry;
    const auto& t = phantom.truth;
    std::map<int64_t, double> arcOf;  // linear index -> nearest arc, for mask voxels
    const auto arc = [&](int64_t i, int64_t j, int64_t k) {
        const int64_t lin = i + g.size[0] * (j + g.size[1] * k);
        auto it = arcOf.find(lin);
        if (it == arcOf.end())
            it = arcOf.emplace(lin, nearestTubeArcMm(t, g.worldFromIndex({double(i), double(j), double(k)}))).first;
        return it->second;
    };
    int64_t touches = 0;
    for (int64_t k = 0; k + 1 < g.size[2]; ++k)
        for (int64_t j = 0; j + 1 < g.size[1]; ++j)
            for (int64_t i = 0; i + 1 < g.size[0]; ++i) {
                if (!phantom.truthLumen.at(i, j, k)) continue;
                for (int d = 0; d < 3; ++d) {
                    const int64_t i2 = i + (d == 0), j2 = j + (d == 1), k2 = k + (d == 2);
                    if (!phantom.truthLumen.at(i2, j2, k2)) continue;
                    if (std::abs(arc(i, j, k) - arc(i2, j2, k2)) <= ph::NON_ADJACENT_ARC_MM) continue;
                    const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                    bool declared = false;
                    for (const PhantomContact& c : t.contacts)
                        declared = declared || distance(w, c.positionMm) < 20.0;
                    // The rectal tube's lumen is not colon: its voxels have no meaningful arc.
                    if (t.hasRectalTube &&
                        ph::rectalTubeDistance(t.rectalTube, w).axisMm < t.rectalTube.outerRadiusMm + 5.0)
                        declared = true;
                    touches += declared ? 0 : 1;
                }
            }
    return touches;
}

double truthLengthMm(const PhantomTruth& t)
{
    double s = 0;
    for (std::size_t i = 1; i < t.centerlineMm.size(); ++i)
        s += distance(t.centerlineMm[i - 1], t.centerlineMm[i]);
    return s;
}

// ---------------------------------------------------------------------------------------

TEST(PhantomContacts, DefaultColonTouchesAtTwoPlacesForTwoSeeds)
{
    for (uint64_t seed : {1u, 2u}) {
        for (int n : {1, 2}) {
            PhantomParams p{PhantomSize::Small, seed, VARIANT_NOISE_HU};
            p.touching = n;
            const Phantom phantom = makePhantom(p);
            ASSERT_EQ(int(phantom.truth.contacts.size()), n) << describe(p);
            expectContactsHold(phantom, describe(p));
            EXPECT_EQ(undeclaredTouches(phantom), 0) << describe(p);
        }
    }
}

TEST(PhantomContacts, RefusesMoreThanTheColonHasRoomFor)
{
    PhantomParams p{PhantomSize::Small, 1, VARIANT_NOISE_HU};
    p.touching = 3;
    try {
        makePhantom(p);
        FAIL() << "3 contacts on the default colon: expected a ParameterError";
    } catch (const ParameterError& e) {
        EXPECT_NE(std::string(e.what()).find("at most 2"), std::string::npos) << e.what();
    }
    p.touching = PHANTOM_MAX_CONTACTS + 1;
    EXPECT_THROW(makePhantom(p), ParameterError);
    p.touching = -1;
    EXPECT_THROW(makePhantom(p), ParameterError);
}

TEST(PhantomRedundant, LongerColonClearOfItselfWithAndWithoutContacts)
{
    PhantomParams plain{PhantomSize::Small, 1, VARIANT_NOISE_HU};
    const double defaultLength = truthLengthMm(makePhantom(plain).truth);
    for (uint64_t seed : {1u, 2u}) {
        PhantomParams p{PhantomSize::Small, seed, VARIANT_NOISE_HU};
        p.redundant = true;
        const Phantom phantom = makePhantom(p);
        SCOPED_TRACE(describe(p));
        const double length = truthLengthMm(phantom.truth);
        // Extra loops: 2.0-2.3 m of colon, as real colons are (the default is ~1.8 m).
        EXPECT_GE(length, 2000.0) << "redundant colon length (mm)";
        EXPECT_LE(length, 2300.0) << "redundant colon length (mm)";
        EXPECT_GE(length, defaultLength + 350.0) << "default colon " << defaultLength << " mm";
        EXPECT_TRUE(phantom.truth.contacts.empty());
        EXPECT_EQ(ph::colonSelfClearance(ph::buildPhantomAnatomy(seed, {true, 0, {2.5, 2.5, 2.5}, false})).gapMm >= ph::MIN_WALL_GAP_MM, true);
        EXPECT_EQ(undeclaredTouches(phantom), 0) << "lumen voxels of non-adjacent parts touch";
        // Still the anatomical order of segments, rectum to cecum.
        EXPECT_EQ(phantom.truth.segment.front(), "rectum");
        EXPECT_EQ(phantom.truth.segment.back(), "cecum");
        EXPECT_GE(phantom.truth.polyps.size(), 6u);

        PhantomParams touching = p;
        touching.touching = seed == 1 ? 5 : 4;
        const Phantom bent = makePhantom(touching);
        ASSERT_EQ(int(bent.truth.contacts.size()), touching.touching) << describe(touching);
        EXPECT_GE(truthLengthMm(bent.truth), 2000.0);
        EXPECT_LE(truthLengthMm(bent.truth), 2300.0);
        expectContactsHold(bent, describe(touching));
        EXPECT_EQ(undeclaredTouches(bent), 0) << describe(touching);
    }
}

/// Face-connected voxels below -400 HU in the CT, from the image corner (outside air) to `goal`.
bool airConnectedToOutside(const Phantom& phantom, const Vec3d& goalMm)
{
    const auto& g = phantom.ct.geometry;
    return faceConnected(g, Index{0, 0, g.size[2] / 2}, nearestVoxel(g, goalMm),
                         [&](const Index& v) { return phantom.ct.at(v[0], v[1], v[2]) < -400; });
}

TEST(PhantomRectalTube, JoinsTheRectumToOutsideAirAndStartsBelowTheColon)
{
    for (uint64_t seed : {1u, 3u}) {
        PhantomParams p{PhantomSize::Small, seed, VARIANT_NOISE_HU};
        p.rectalTube = true;
        const Phantom phantom = makePhantom(p);
        SCOPED_TRACE(describe(p));
        const PhantomTruth& t = phantom.truth;
        ASSERT_TRUE(t.hasRectalTube);
        const PhantomRectalTube& tube = t.rectalTube;
        EXPECT_GE(2.0 * tube.outerRadiusMm, 8.0);
        EXPECT_LE(2.0 * tube.outerRadiusMm, 12.0);
        EXPECT_GE(2.0 * tube.innerRadiusMm, 5.0);
        EXPECT_LE(2.0 * tube.innerRadiusMm, 8.0);
        // Outer end outside the body; tip in the rectum's lumen, a few cm above the verge.
        EXPECT_GT(ph::bodySignedDistanceMm(tube.axisMm.front().x, tube.axisMm.front().y), 10.0);
        const double tipArc = nearestArcMm(t.centerlineMm, tube.tipMm());
        EXPECT_EQ(t.segment[std::size_t(tipArc)], "rectum");
        EXPECT_LT(distance(tube.tipMm(), t.centerlineMm[std::size_t(tipArc)]), 2.0);
        EXPECT_GE(tipArc, 20.0);
        EXPECT_LE(tipArc, 60.0);
        // The truth centerline starts at the anal verge, below the tip, on the tube's axis.
        EXPECT_LT(t.centerlineMm.front().z, tube.tipMm().z - 20.0);
        EXPECT_LT(ph::rectalTubeDistance(tube, t.centerlineMm.front()).axisMm, 0.5);

        // CT: the colon's air is joined to the outside air through the tube's lumen (not
        // without the tube), and the tube's wall is plastic.
        const Vec3d aboveTip = t.centerlineMm[std::size_t(tipArc) + 25];
        EXPECT_TRUE(airConnectedToOutside(phantom, aboveTip)) << "rectum air not joined to outside air";
        PhantomParams noTube = p;
        noTube.rectalTube = false;
        const Phantom plain = makePhantom(noTube);
        EXPECT_FALSE(airConnectedToOutside(plain, aboveTip)) << "without a tube the colon must be closed";

        // Mask: the tube's air lumen inside the body is in it, connected to the rectum; the
        // colon's own lumen is that of the phantom without the tube, voxel for voxel.
        const auto& g = phantom.truthLumen.geometry;
        const Vec3d inBody = (tube.axisMm[2] + tube.axisMm[3]) * 0.5;
        const auto mask = [&](const Index& v) { return phantom.truthLumen.at(v[0], v[1], v[2]) != 0; };
        EXPECT_TRUE(faceConnected(g, nearestVoxel(g, inBody), nearestVoxel(g, aboveTip), mask))
            << "the tube's lumen in the mask is not connected to the rectum";
        EXPECT_DOUBLE_EQ(t.colonLumenVolumeMl, plain.truth.lumenVolumeMl);
        EXPECT_GT(t.tubeLumenVolumeMl, 0.5);
        EXPECT_LT(t.tubeLumenVolumeMl, 10.0);
        EXPECT_FALSE(phantom.truthLumen.voxels == plain.truthLumen.voxels);
        // The same anatomy otherwise: polyps and centerline are those of the plain phantom.
        EXPECT_EQ(t.centerlineMm.size(), plain.truth.centerlineMm.size());
        EXPECT_EQ(t.polyps.size(), plain.truth.polyps.size());
    }
}

// The tube's tip is open: its air meets the rectum's air there at the segmentation's air
// threshold (-800 HU), whatever the voxel grid. Painting the rod's wall and then its air over
// it left a quarter of the wall in the voxels within half a slice of the tip plane (-700 HU
// over the whole lumen: a cap), which closed the tip on grids with a slice centre near it
// (the medium size's 1.5 mm slices: the tube's air became a separate 5 mL piece, the tube was
// never found and the path ran 14 mm beside it the whole length of the rectum).
TEST(PhantomRectalTube, OpenTipJoinsTheTubesAirToTheRectumsAirAtTheAirThreshold)
{
    PhantomParams p{PhantomSize::Small, 1, VARIANT_NOISE_HU};
    p.rectalTube = true;
    p.spacingMm = {2.5, 2.5, 1.5};  // the medium size's slices: a slice centre 0.16 mm below the tip
    const Phantom phantom = makePhantom(p);
    SCOPED_TRACE(describe(p));
    const PhantomRectalTube& tube = phantom.truth.rectalTube;
    const auto& g = phantom.ct.geometry;
    const Vec3d tip = tube.tipMm();
    const Vec3d dir = normalize(tip - tube.axisMm[tube.axisMm.size() - 2]);
    const Index below = nearestVoxel(g, tip - dir * 6.0), above = nearestVoxel(g, tip + dir * 6.0);
    const auto air = [&](const Index& v) { return phantom.ct.at(v[0], v[1], v[2]) < -800; };
    // Within the rod's reach of the tip (the tube's own air and the rectum's around its end).
    const auto nearTip = [&](const Index& v) {
        const Vec3d w = g.worldFromIndex({double(v[0]), double(v[1]), double(v[2])});
        return air(v) && distance(w, tip) < 12.0;
    };
    ASSERT_TRUE(air(below)) << "no air voxel on the tube's axis 6 mm below its tip: "
                            << phantom.ct.at(below[0], below[1], below[2]) << " HU";
    double worst = -1000;
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                const ph::TubeDistance d = ph::rectalTubeDistance(tube, w);
                if (d.axisMm < tube.innerRadiusMm - 1.5 && std::abs(d.beyondTipMm) < 0.75)
                    worst = std::max(worst, double(phantom.ct.at(i, j, k)));
            }
    EXPECT_LT(worst, -800.0) << "HU of the tube's lumen at its open tip plane (the highest seen)";
    EXPECT_TRUE(faceConnected(g, below, above, nearTip))
        << "the tube's air is not joined to the rectum's air through its open tip (air below -800 HU)";
}

TEST(PhantomSpacing, AnisotropicVoxelsKeepTheWorldGeometry)
{
    PhantomParams iso{PhantomSize::Small, 1, VARIANT_NOISE_HU};
    PhantomParams aniso = iso;
    aniso.spacingMm = {2.0, 2.0, 3.0};
    const Phantom a = makePhantom(iso), b = makePhantom(aniso);
    const auto& g = b.truthLumen.geometry;
    EXPECT_EQ(g.spacingMm.x, 2.0);
    EXPECT_EQ(g.spacingMm.y, 2.0);
    EXPECT_EQ(g.spacingMm.z, 3.0);
    EXPECT_EQ(g.size[0], 200);
    EXPECT_EQ(g.size[1], 200);
    EXPECT_EQ(g.size[2], 125);
    EXPECT_TRUE(b.ct.geometry.spacingMm == g.spacingMm);
    // Same centred field of view.
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(g.originMm[c] + 0.5 * double(g.size[std::size_t(c)] - 1) * g.spacingMm[c], 0.0, 1e-9);
    const auto centroid = [](const Image3<uint8_t>& m) {
        Vec3d s{0, 0, 0};
        double n = 0;
        const auto& gg = m.geometry;
        for (int64_t k = 0; k < gg.size[2]; ++k)
            for (int64_t j = 0; j < gg.size[1]; ++j)
                for (int64_t i = 0; i < gg.size[0]; ++i)
                    if (m.at(i, j, k)) {
                        s += gg.worldFromIndex({double(i), double(j), double(k)});
                        n += 1;
                    }
        return s / n;
    };
    const Vec3d ca = centroid(a.truthLumen), cb = centroid(b.truthLumen);
    for (int c = 0; c < 3; ++c)
        EXPECT_LT(std::abs(ca[c] - cb[c]), 0.5 * g.spacingMm[c]) << "mask centroid moved along axis " << c;
    EXPECT_NEAR(a.truth.lumenVolumeMl, b.truth.lumenVolumeMl, 0.03 * a.truth.lumenVolumeMl);
    EXPECT_EQ(a.truth.centerlineMm.size(), b.truth.centerlineMm.size());
    EXPECT_EQ(a.truth.polyps.size(), b.truth.polyps.size());
    // Default spacing: the size's own geometry, byte for byte.
    EXPECT_EQ(phantomImageGeometry(iso).size, ph::phantomGeometry(PhantomSize::Small).size);

    for (const Vec3d bad : {Vec3d{0.1, 1, 1}, Vec3d{1, 1, 6}, Vec3d{1, -1, 1}, Vec3d{1, 1, std::nan("")}}) {
        PhantomParams p = iso;
        p.spacingMm = bad;
        EXPECT_THROW(phantomImageGeometry(p), ParameterError);
    }
    EXPECT_THROW(parsePhantomSpacing("0.8,0.8"), ParameterError);
    EXPECT_THROW(parsePhantomSpacing("0.8,0.8,x"), ParameterError);
    EXPECT_THROW(parsePhantomSpacing("0.8,0.8,1.25,1"), ParameterError);
    EXPECT_THROW(parsePhantomSpacing("0.8,0.8,100"), ParameterError);
    EXPECT_TRUE(parsePhantomSpacing("0.8,0.8,1.25") == (Vec3d{0.8, 0.8, 1.25}));
}

// The stricture: the truth lists one narrowing of the transverse colon, the truth radii follow
// it, and the truth mask narrows there to about the listed radius while the colon stays one
// face-connected lumen through it; the truth JSON keeps it.
TEST(PhantomStricture, NarrowsTheTransverseColonAndKeepsItOnePiece)
{
    for (uint64_t seed : {1u, 2u}) {
        PhantomParams p;
        p.seed = seed;
        p.stricture = true;
        SCOPED_TRACE(describe(p));
        const Phantom phantom = makePhantom(p);
        const PhantomTruth& t = phantom.truth;
        ASSERT_EQ(t.strictures.size(), 1u);
        const PhantomStricture& st = t.strictures[0];
        const auto mid = std::size_t(std::lround(0.5 * (st.arcStartMm + st.arcEndMm)));
        EXPECT_EQ(t.segment[mid], "transverse");
        EXPECT_DOUBLE_EQ(st.minRadiusMm, 4.0) << "max(3 mm, 1.6 voxels of 2.5 mm)";
        EXPECT_DOUBLE_EQ(t.radiusMm[mid], st.minRadiusMm);
        EXPECT_GT(t.radiusMm[std::size_t(st.arcStartMm) - 5], 3.0 * st.minRadiusMm) << "the colon before it";
        EXPECT_GT(t.radiusMm[std::size_t(st.arcEndMm) + 5], 3.0 * st.minRadiusMm) << "the colon after it";
        EXPECT_LE(st.arcEndMm - st.arcStartMm, 18.0 + 1e-9);
        EXPECT_GE(st.arcEndMm - st.arcStartMm, 14.0 - 1e-9);
        // The truth mask across the middle: lumen voxels within 1.5 radii of the axis point, in
        // the plane through it across the tube, against the disc of the listed radius.
        const ImageGeometry& g = phantom.truthLumen.geometry;
        const Vec3d c = t.centerlineMm[mid];
        const Vec3d tangent = normalize(t.centerlineMm[mid + 2] - t.centerlineMm[mid - 2]);
        int64_t across = 0, far = 0;
        const double voxelMm = g.spacingMm.x;
        for (int64_t k = 0; k < g.size[2]; ++k)
            for (int64_t j = 0; j < g.size[1]; ++j)
                for (int64_t i = 0; i < g.size[0]; ++i) {
                    const Vec3d w = g.worldFromIndex(Vec3d{double(i), double(j), double(k)});
                    const Vec3d d = w - c;
                    if (std::abs(dot(d, tangent)) > 0.5 * voxelMm || length(d) > 6.0 * st.minRadiusMm) continue;
                    if (!phantom.truthLumen.voxels[std::size_t(i + g.size[0] * (j + g.size[1] * k))]) continue;
                    ++across;
                    far += length(d) > st.minRadiusMm + voxelMm;
                }
        EXPECT_GT(across, 0) << "no lumen across the stricture's middle";
        EXPECT_EQ(far, 0) << "lumen voxels in the stricture's plane beyond its radius plus a voxel";
        // One lumen through it: face-connected from before the stricture to after it.
        const Index before = nearestVoxel(g, t.centerlineMm[std::size_t(st.arcStartMm) - 10]);
        const Index after = nearestVoxel(g, t.centerlineMm[std::size_t(st.arcEndMm) + 10]);
        EXPECT_TRUE(faceConnected(g, before, after, [&](const Index& v) {
            return phantom.truthLumen.voxels[std::size_t(v[0] + g.size[0] * (v[1] + g.size[1] * v[2]))] != 0;
        })) << "the lumen before and after the stricture";
        const PhantomTruth back = phantomTruthFromJson(phantomTruthToJson(phantom, p), "test");
        ASSERT_EQ(back.strictures.size(), 1u);
        EXPECT_EQ(back.strictures[0].arcStartMm, st.arcStartMm);
        EXPECT_EQ(back.strictures[0].arcEndMm, st.arcEndMm);
        EXPECT_EQ(back.strictures[0].minRadiusMm, st.minRadiusMm);
    }
    // Without the variant: none, and the default phantom is unchanged by the variant's code.
    EXPECT_TRUE(makePhantom(PhantomParams{}).truth.strictures.empty());
}

// Defect: the stricture narrowed the lumen wherever the nearest centerline sample *among
// those round the stricture* lay in it, so a loop passing within reach of it lost a slab of
// its lumen (seed 1 with the redundant colon at 1.6 x 1.6 x 2.5 mm: 7.3 k voxels of the loops
// 66-85 mm away, at truth arcs 1200-1250 and 1800-1850; the path ran there 11 mm off the
// truth and 4 mm from the wall). The stricture may change only the colon round it: the lumen
// it takes lies nearest to the truth centerline within its arc (plus 3 mm and a voxel), and
// the lumen it gives (the folds it removes, 3-5 mm thick, reaching up to twice that past it)
// within 10 mm and a voxel of it.
TEST(PhantomStricture, ChangesTheLumenOnlyWhereItIs)
{
    struct Case {
        uint64_t seed;
        bool redundant;
        int touching;
        Vec3d spacingMm;
    };
    for (const Case& c : {Case{1, true, 2, {1.6, 1.6, 2.5}}, Case{2, true, 2, {1.6, 1.6, 2.5}}, Case{1, false, 0, {}},
                          Case{2, false, 0, {}}}) {
        PhantomParams p;
        p.seed = c.seed;
        p.redundant = c.redundant;
        p.touching = c.touching;
        if (c.spacingMm.x > 0) p.spacingMm = c.spacingMm;
        const Phantom plain = makePhantom(p);
        p.stricture = true;
        SCOPED_TRACE(describe(p));
        const Phantom narrowed = makePhantom(p);
        ASSERT_EQ(narrowed.truth.strictures.size(), 1u);
        const PhantomStricture& st = narrowed.truth.strictures[0];
        const ImageGeometry& g = narrowed.truthLumen.geometry;
        ASSERT_EQ(plain.truthLumen.voxels.size(), narrowed.truthLumen.voxels.size());
        const double voxelMm = std::max({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z});
        int64_t taken = 0, given = 0, takenElsewhere = 0, givenElsewhere = 0;
        double takenArc = 0, givenArc = 0;
        for (int64_t k = 0; k < g.size[2]; ++k)
            for (int64_t j = 0; j < g.size[1]; ++j)
                for (int64_t i = 0; i < g.size[0]; ++i) {
                    const std::size_t v = std::size_t(i + g.size[0] * (j + g.size[1] * k));
                    if (plain.truthLumen.voxels[v] == narrowed.truthLumen.voxels[v]) continue;
                    const bool took = plain.truthLumen.voxels[v] != 0;
                    const double margin = (took ? 3.0 : 10.0) + voxelMm;
                    const double arc = test::nearestArcMm(narrowed.truth.centerlineMm,
                                                          g.worldFromIndex(Vec3d{double(i), double(j), double(k)}));
                    const bool away = arc < st.arcStartMm - margin || arc > st.arcEndMm + margin;
                    (took ? taken : given) += 1;
                    if (!away) continue;
                    (took ? takenElsewhere : givenElsewhere) += 1;
                    (took ? takenArc : givenArc) = arc;
                }
        EXPECT_GT(taken, 0) << "the stricture took no lumen";
        EXPECT_EQ(takenElsewhere, 0) << "lumen voxels taken away from the stricture (arc " << st.arcStartMm << "-"
                                     << st.arcEndMm << " mm), e.g. one nearest to truth arc " << takenArc << " mm";
        EXPECT_EQ(givenElsewhere, 0) << "lumen voxels given away from the stricture (arc " << st.arcStartMm << "-"
                                     << st.arcEndMm << " mm), e.g. one nearest to truth arc " << givenArc << " mm";
        std::printf("[ %s ] stricture at arc %.0f-%.0f mm: %lld lumen voxels taken, %lld given (folds removed)\n",
                    describe(p).c_str(), st.arcStartMm, st.arcEndMm, static_cast<long long>(taken),
                    static_cast<long long>(given));
    }
}

// The truth centerline runs inside the truth lumen (but where the colon is collapsed): every
// 1 mm sample's nearest voxel is lumen. Defect: a haustral fold is a slab along its plane
// beyond its rim, and it was applied wherever it was the nearest fold in arc; with --touching
// the bent sigmoid's first fold's plane crossed the rectum 80-90 mm further down the colon,
// and a slab of tissue closed the whole rectum (truth arcs 61-65 in the wall on every seed;
// the path squeezed through a gap beside it, up to 10 mm off the truth).
TEST(PhantomTruth, CenterlineRunsInsideTheLumen)
{
    auto variant = [](uint64_t seed, const std::function<void(PhantomParams&)>& set) {
        PhantomParams p;
        p.seed = seed;
        set(p);
        return p;
    };
    for (const PhantomParams& p :
         {variant(1, [](PhantomParams&) {}), variant(1, [](PhantomParams& v) { v.touching = 2; }),
          variant(2, [](PhantomParams& v) { v.touching = 2, v.rectalTube = v.fluid = true; }),
          variant(3, [](PhantomParams& v) { v.touching = 2, v.collapse = true; }),
          variant(1, [](PhantomParams& v) { v.redundant = true, v.touching = 5; }),
          variant(2, [](PhantomParams& v) { v.redundant = true, v.touching = 2, v.rectalTube = v.fluid = v.stricture = true; }),
          variant(3, [](PhantomParams& v) { v.touching = 2, v.rectalTube = v.fluid = v.prone = true, v.orientation = "RAS"; })}) {
        SCOPED_TRACE(describe(p));
        const Phantom ph = makePhantom(p);
        const ImageGeometry& g = ph.truthLumen.geometry;
        int64_t outside = 0;
        std::size_t firstOutside = 0;
        for (std::size_t a = 0; a < ph.truth.centerlineMm.size(); ++a) {
            bool collapsed = false;
            for (const PhantomCollapse& cs : ph.truth.collapsed)
                collapsed = collapsed || (double(a) >= cs.arcStartMm - 3.0 && double(a) <= cs.arcEndMm + 3.0);
            if (collapsed) continue;
            const Index v = nearestVoxel(g, ph.truth.centerlineMm[a]);
            if (ph.truthLumen.voxels[std::size_t(v[0] + g.size[0] * (v[1] + g.size[1] * v[2]))]) continue;
            if (outside++ == 0) firstOutside = a;
        }
        EXPECT_EQ(outside, 0) << "truth centerline samples outside the truth lumen, the first at arc " << firstOutside
                              << " mm";
    }
}

TEST(PhantomOrientation, StoresTheSameWorldAnatomyInAnotherVoxelOrder)
{
    PhantomParams lps{PhantomSize::Small, 2, VARIANT_NOISE_HU};
    lps.fluid = lps.rectalTube = true;
    lps.spacingMm = {2.0, 2.5, 3.0};  // three sizes: a permuted axis shows in the spacing
    const Phantom ref = makePhantom(lps);
    const ImageGeometry& rg = ref.ct.geometry;
    struct Expect {
        const char* code;
        Mat3d direction;
    };
    for (const Expect& e : {Expect{"RAS", {{{-1, 0, 0}, {0, -1, 0}, {0, 0, 1}}}},
                            Expect{"las", {{{1, 0, 0}, {0, -1, 0}, {0, 0, 1}}}},
                            Expect{"SLP", {{{0, 1, 0}, {0, 0, 1}, {1, 0, 0}}}},
                            Expect{"IRA", {{{0, -1, 0}, {0, 0, -1}, {-1, 0, 0}}}}}) {
        SCOPED_TRACE(e.code);
        PhantomParams p = lps;
        p.orientation = e.code;
        const Phantom ph = makePhantom(p);
        const ImageGeometry& g = ph.ct.geometry;
        EXPECT_TRUE(g.direction == e.direction);
        EXPECT_TRUE(ph.truthLumen.geometry.direction == e.direction);
        EXPECT_EQ(g.voxelCount(), rg.voxelCount());
        // Every voxel holds what the LPS phantom holds at the same world position.
        int64_t differ = 0, off = 0;
        for (int64_t k = 0; k < g.size[2]; ++k)
            for (int64_t j = 0; j < g.size[1]; ++j)
                for (int64_t i = 0; i < g.size[0]; ++i) {
                    const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                    const Vec3d r = rg.indexFromWorld(w);
                    const Index v = nearestVoxel(rg, w);
                    off += std::abs(r.x - double(v[0])) + std::abs(r.y - double(v[1])) + std::abs(r.z - double(v[2])) > 1e-6;
                    differ += ph.ct.at(i, j, k) != ref.ct.at(v[0], v[1], v[2]) ||
                              ph.truthLumen.at(i, j, k) != ref.truthLumen.at(v[0], v[1], v[2]);
                }
        EXPECT_EQ(off, 0) << "voxel centres off the LPS phantom's lattice";
        EXPECT_EQ(differ, 0) << "voxels that differ from the LPS phantom's at the same world position";
        EXPECT_TRUE(ph.truth.centerlineMm == ref.truth.centerlineMm);
        EXPECT_EQ(ph.truth.lumenVolumeMl, ref.truth.lumenVolumeMl);
        EXPECT_EQ(ph.truth.fluidVolumeMl, ref.truth.fluidVolumeMl);
        EXPECT_EQ(phantomTruthToJson(ph, p).at("variants").at("orientation"), e.code);
    }
    for (const char* bad : {"LLS", "LP", "LPSX", "XPS", "LPA"}) {
        PhantomParams p = lps;
        p.orientation = bad;
        EXPECT_THROW(makePhantom(p), ParameterError) << bad;
    }
}

TEST(PhantomIleum, GasJoinsTheCecumAndStaysOutOfTheMask)
{
    for (const bool redundant : {false, true}) {
        PhantomParams p{PhantomSize::Small, 2, VARIANT_NOISE_HU};
        p.ilealReflux = true;
        p.redundant = redundant;
        p.touching = redundant ? 3 : 2;
        SCOPED_TRACE(describe(p) + " ileal reflux");
        const Phantom ph = makePhantom(p);
        const PhantomTruth& t = ph.truth;
        ASSERT_GT(t.ileumMm.size(), 150u);
        EXPECT_EQ(t.ileumRadiusMm, 11.0);
        const double colonLength = double(t.centerlineMm.size() - 1);
        EXPECT_NEAR(t.ileumValveArcMm, colonLength - 50.0, 1.0);
        const auto& g = ph.ct.geometry;
        // Its gas: air in the CT along the axis past the valve, none of it in the truth mask,
        // and face-connected (air below -500 HU) from its blind end to the cecum's axis.
        int64_t air = 0, inMask = 0;
        for (std::size_t s = 40; s < t.ileumMm.size(); s += 5) {
            const Index v = nearestVoxel(g, t.ileumMm[s]);
            air += ph.ct.at(v[0], v[1], v[2]) < -800;
            inMask += ph.truthLumen.at(v[0], v[1], v[2]) != 0;
        }
        EXPECT_EQ(air, int64_t((t.ileumMm.size() - 41) / 5 + 1));
        EXPECT_EQ(inMask, 0);
        const auto isAir = [&](const Index& v) { return ph.ct.at(v[0], v[1], v[2]) < -500; };
        EXPECT_TRUE(faceConnected(g, nearestVoxel(g, t.ileumMm[t.ileumMm.size() - 5]),
                                  nearestVoxel(g, t.centerlineMm[t.centerlineMm.size() - 20]), isAir))
            << "the ileum's gas does not reach the cecum's";
        EXPECT_GT(t.ileumLumenVolumeMl, 30.0);
        // The colon itself is the one without the ileum, voxel for voxel in the mask.
        PhantomParams plain = p;
        plain.ilealReflux = false;
        EXPECT_TRUE(makePhantom(plain).truthLumen.voxels == ph.truthLumen.voxels);
        // The truth JSON carries it and reads back.
        const PhantomTruth back = phantomTruthFromJson(phantomTruthToJson(ph, p), "test");
        EXPECT_EQ(back.ileumMm.size(), t.ileumMm.size());
        EXPECT_EQ(back.ileumRadiusMm, t.ileumRadiusMm);
        EXPECT_EQ(back.ileumValveArcMm, t.ileumValveArcMm);
    }
}

TEST(PhantomAllVariants, TogetherOnAnisotropicVoxelsAndThroughTheTruthJson)
{
    PhantomParams p{PhantomSize::Small, 2, VARIANT_NOISE_HU};
    p.redundant = true;
    p.touching = 3;
    p.rectalTube = true;
    p.fluid = true;
    p.collapse = true;
    p.spacingMm = {2.0, 2.0, 3.0};
    const Phantom phantom = makePhantom(p);
    SCOPED_TRACE(describe(p));
    ASSERT_EQ(phantom.truth.contacts.size(), 3u);
    EXPECT_TRUE(phantom.truth.hasRectalTube);
    EXPECT_FALSE(phantom.truth.collapsed.empty());
    EXPECT_EQ(phantom.truth.fluidPools.size(), 3u);
    EXPECT_GE(truthLengthMm(phantom.truth), 1750.0);
    expectContactsHold(phantom, describe(p));
    for (const PhantomCollapse& c : phantom.truth.collapsed)
        for (const PhantomContact& k : phantom.truth.contacts)
            for (double arc : {k.arcAMm, k.arcBMm})
                EXPECT_TRUE(arc < c.arcStartMm || arc > c.arcEndMm) << "a contact inside a collapsed stretch";
    EXPECT_TRUE(airConnectedToOutside(phantom, phantom.truth.centerlineMm[70]));
    // The tube's air lumen in the mask stays face-connected to the rectum on 3 mm slices.
    {
        const auto& g = phantom.truthLumen.geometry;
        const auto& axis = phantom.truth.rectalTube.axisMm;
        const auto mask = [&](const Index& v) { return phantom.truthLumen.at(v[0], v[1], v[2]) != 0; };
        EXPECT_TRUE(faceConnected(g, nearestVoxel(g, (axis[2] + axis[3]) * 0.5),
                                  nearestVoxel(g, phantom.truth.centerlineMm[70]), mask))
            << "the tube's lumen in the mask is not connected to the rectum";
    }

    // The truth JSON carries every variant and reads back.
    const nlohmann::json j = phantomTruthToJson(phantom, p);
    EXPECT_EQ(j.at("world_frame"), "LPS");
    EXPECT_EQ(j.at("contacts").size(), 3u);
    EXPECT_TRUE(j.contains("rectal_tube"));
    EXPECT_TRUE(j.at("centerline").contains("length_mm"));
    const PhantomTruth back = phantomTruthFromJson(j, "test");
    ASSERT_EQ(back.contacts.size(), phantom.truth.contacts.size());
    for (std::size_t n = 0; n < back.contacts.size(); ++n) {
        EXPECT_TRUE(back.contacts[n].positionMm == phantom.truth.contacts[n].positionMm);
        EXPECT_EQ(back.contacts[n].widthMm, phantom.truth.contacts[n].widthMm);
        EXPECT_EQ(back.contacts[n].arcAMm, phantom.truth.contacts[n].arcAMm);
        EXPECT_EQ(back.contacts[n].arcBMm, phantom.truth.contacts[n].arcBMm);
    }
    EXPECT_TRUE(back.hasRectalTube);
    EXPECT_EQ(back.rectalTube.axisMm.size(), phantom.truth.rectalTube.axisMm.size());
    EXPECT_EQ(back.collapsed.size(), phantom.truth.collapsed.size());
    EXPECT_EQ(back.fluidPools.size(), phantom.truth.fluidPools.size());
    EXPECT_EQ(back.colonLumenVolumeMl, phantom.truth.colonLumenVolumeMl);

    // The default truth JSON has none of the variant keys (unchanged for existing readers).
    PhantomParams plain{PhantomSize::Small, 2, VARIANT_NOISE_HU};
    const nlohmann::json d = phantomTruthToJson(makePhantom(plain), plain);
    for (const char* key : {"contacts", "rectal_tube", "variants", "colon_lumen_volume_ml"})
        EXPECT_FALSE(d.contains(key)) << key;
}

} // namespace
