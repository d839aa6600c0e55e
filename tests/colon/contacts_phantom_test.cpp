// Contacts between touching loops on the phantoms with truth (colon/phantom.h, --touching N):
// every truth contact found and cut, the path from the rectum to the cecum through every loop
// (no jump along the truth arc), its error to the truth centerline and its length; from the
// CT and from the truth mask alone, several seeds, with the other difficulties together.
#include "colon/phantom.h"
#include "tests/colon/truth_arc.h"
#include "colon/centerline.h"
#include "volume/error.h"
#include "colon/contacts.h"
#include "colon/lumen_accounting.h"
#include "volume/ingest.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace flyover;

struct Variant {
    uint64_t seed;
    int touching;
    bool fromCt;
    bool collapse = false;
    bool fluid = false;
    bool stricture = false;
    bool redundant = false;
    bool wideRectum = false;
    std::string describe() const
    {
        std::ostringstream s;
        s << "phantom small seed=" << seed << " touching=" << touching << (collapse ? " collapse" : "")
          << (fluid ? " fluid" : "") << (stricture ? " stricture" : "") << (redundant ? " redundant" : "")
          << (wideRectum ? " wide rectum" : "") << (fromCt ? " from CT" : " from the truth mask");
        return s.str();
    }
};

LumenSegmentation segmentPhantom(const Phantom& ph, bool fromCt)
{
    if (fromCt) {
        Image3<float> ct;
        ct.geometry = ph.ct.geometry;
        ct.voxels.assign(ph.ct.voxels.begin(), ph.ct.voxels.end());
        return segmentLumen(*ingestImage(ct, IngestParams{}), SegmentParams{});
    }
    Image3<float> mask;
    mask.geometry = ph.truthLumen.geometry;
    mask.voxels.assign(ph.truthLumen.voxels.begin(), ph.truthLumen.voxels.end());
    return segmentFromMask(mask, SegmentParams{});
}

void runVariant(const Variant& v)
{
    SCOPED_TRACE(v.describe());
    PhantomParams pp;
    pp.seed = v.seed;
    pp.touching = v.touching;
    pp.collapse = v.collapse;
    pp.fluid = v.fluid;
    pp.stricture = v.stricture;
    pp.redundant = v.redundant;
    pp.wideRectum = v.wideRectum;
    Phantom ph;
    try {
        ph = makePhantom(pp);
    } catch (const ParameterError& e) {
        FAIL() << "the phantom generator could not make this variant: " << e.what();
    }
    ASSERT_EQ(ph.truth.contacts.size(), std::size_t(v.touching));
    LumenSegmentation seg = segmentPhantom(ph, v.fromCt);
    const ContactReport contacts = cutContacts(*seg.sdf, seg.mask.get(), ContactParams{});
    CenterlineReport cr;
    const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{}, nullptr, &cr);
    ASSERT_GE(cl.points.size(), 10u);
    const std::vector<Vec3d>& truth = ph.truth.centerlineMm;  // 1 mm samples, rectum first
    const double truthLength = double(truth.size() - 1);

    // Path against the truth: error (nearest truth sample), truth arc of every point.
    std::vector<double> err, arc;
    for (const CenterlinePoint& p : cl.points) {
        const double a = test::nearestArcMm(truth, p.positionMm);
        arc.push_back(a);
        err.push_back(distance(truth[std::size_t(a)], p.positionMm));
    }
    // Error away from bridges and the last 10 mm at each end (the path stops short of caps).
    std::vector<double> inner;
    for (std::size_t i = 0; i < err.size(); ++i)
        if (!cl.points[i].bridged && arc[i] > 10 && arc[i] < truthLength - 10) inner.push_back(err[i]);
    ASSERT_FALSE(inner.empty());
    double mean = 0;
    for (double e : inner) mean += e / double(inner.size());
    std::sort(inner.begin(), inner.end());
    const double p95 = inner[std::size_t(0.95 * double(inner.size() - 1))];
    double worstJump = 0;
    for (std::size_t i = 1; i < arc.size(); ++i) worstJump = std::max(worstJump, std::abs(arc[i] - arc[i - 1]));
    const double span = arc.back() - arc.front();

    // Every truth contact found (a cut one within a few mm of it).
    std::size_t cut = 0, matched = 0;
    for (const ContactInfo& c : contacts.contacts) cut += c.cut;
    for (const PhantomContact& t : ph.truth.contacts) {
        double best = 1e9;
        for (const ContactInfo& c : contacts.contacts)
            if (c.cut) best = std::min(best, distance(c.positionMm, t.positionMm));
        const double tolerance = 3.0 * ph.ct.geometry.spacingMm.x + 0.5 * t.widthMm;
        matched += best <= tolerance;
        EXPECT_LE(best, tolerance) << "truth contact at (" << t.positionMm.x << ", " << t.positionMm.y << ", "
                                   << t.positionMm.z << "), arcs " << t.arcAMm << "/" << t.arcBMm;
    }
    std::printf("[ %s ] contacts: %zu truth, %zu found, %zu cut; path %.1f mm vs truth %.1f mm (ratio %.3f), "
                "error mean %.2f p95 %.2f mm, largest jump along the truth %.1f mm, starts at truth arc %.1f, "
                "ends at %.1f\n",
                v.describe().c_str(), ph.truth.contacts.size(), matched, cut, cl.lengthMm(), truthLength,
                cl.lengthMm() / truthLength, mean, p95, worstJump, arc.front(), arc.back());
    // No cut where there is no contact: a false cut can split the colon and drop a stretch.
    EXPECT_EQ(cut, ph.truth.contacts.size()) << "contacts cut vs truth";
    EXPECT_LE(mean, 1.0 + 0.25 * ph.ct.geometry.spacingMm.x) << "mean error to the truth centerline (mm)";
    EXPECT_LE(worstJump, 20.0) << "consecutive points jump along the truth arc: a shortcut";
    EXPECT_LT(arc.front(), 15.0) << "the path starts in the rectum";
    EXPECT_GT(arc.back(), truthLength - 25.0) << "the path ends in the cecum";
    EXPECT_NEAR(span, truthLength, 0.03 * truthLength) << "truth span of the path";
    EXPECT_NEAR(cl.lengthMm(), span, 0.03 * span) << "path length vs the truth between its ends";
    // No kink: the camera never spins.
    EXPECT_EQ(cr.turnsOver30, 0) << "steps turning more than 30 degrees (largest " << cr.maxTurnDeg << ")";
    EXPECT_EQ(cr.normalStepsOver15, 0) << "camera-normal steps over 15 degrees (largest " << cr.maxNormalStepDeg << ")";
    EXPECT_TRUE(cr.leftOut.empty() || std::all_of(cr.leftOut.begin(), cr.leftOut.end(), [](const LeftOutLumen& r) {
        return r.kind != "not entered";
    })) << "a loop of the phantom's colon was not entered";

    // A stricture splits the core of its piece: the route runs the core with corridors, on the
    // whole piece's route, and the path runs through the narrowing on its axis.
    ASSERT_EQ(ph.truth.strictures.size(), v.stricture ? 1u : 0u);
    for (const PhantomStricture& st : ph.truth.strictures) {
        std::size_t onCorridors = 0;
        for (const CenterlinePieceInfo& piece : cr.pieces) onCorridors += piece.routeSearchedOn == "core and corridors";
        EXPECT_EQ(onCorridors, 1u) << "pieces whose route was searched on the core with corridors";
        CenterlineParams whole;
        whole.corridorMm = 0;
        const Centerline wl = extractCenterline(*seg.sdf, whole);
        ASSERT_EQ(wl.points.size(), cl.points.size()) << "points with corridors, and on the whole piece";
        std::size_t differ = 0;
        for (std::size_t i = 0; i < cl.points.size(); ++i) differ += !(cl.points[i].positionMm == wl.points[i].positionMm);
        EXPECT_EQ(differ, 0u) << "path points that differ between the corridors' route and the whole piece's";
        double worst = 0;
        std::size_t inside = 0;
        for (std::size_t i = 0; i < err.size(); ++i)
            if (arc[i] >= st.arcStartMm && arc[i] <= st.arcEndMm) {
                worst = std::max(worst, err[i]);
                ++inside;
            }
        std::printf("[ %s ] stricture at arc %.0f-%.0f mm, radius %.1f mm: %zu path points in it, %.2f mm off the "
                    "truth at most\n",
                    v.describe().c_str(), st.arcStartMm, st.arcEndMm, st.minRadiusMm, inside, worst);
        EXPECT_GE(inside, std::size_t((st.arcEndMm - st.arcStartMm) / CenterlineParams{}.stepMm) / 2)
            << "path points within the stricture's arc";
        EXPECT_LE(worst, 0.5 * st.minRadiusMm) << "mm between the path and the stricture's axis";
    }
}

TEST(ContactsPhantom, TouchingLoopsFromTheMaskSeveralSeeds)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2, 3}) runVariant({seed, 2, false});
}

// From the CT: the lumen after the threshold and the cleansing of tagged fluid. With collapsed
// stretches between the touching loops the contacts close no cycle (every seed): they are found
// as narrow links that meet a tube from the side on both hands, and the path bridges the
// collapses.
TEST(ContactsPhantom, TouchingLoopsFromTheCt)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2, 3}) runVariant({seed, 2, true});
}

TEST(ContactsPhantom, TouchingWithCollapseAndFluidFromTheCt)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2, 3}) runVariant({seed, 2, true, true, true});
}

// The rectum the widest lumen (radius ~31 mm over its lowest 50 mm) and the sigmoid packed
// against the other loops with every contact the longer colon has: the path starts in the
// rectum, never kinks and enters every loop; from the mask and from the CT, several seeds.
TEST(ContactsPhantom, WideRectumBesidePackedLoops)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2}) {
        Variant v{seed, PHANTOM_MAX_CONTACTS, false};
        v.redundant = true;
        v.wideRectum = true;
        runVariant(v);
        v.fromCt = true;
        runVariant(v);
    }
}

// A stricture (an abrupt narrowing to a radius of 4 mm over 8-12 mm of the transverse colon at
// the small phantom's 2.5 mm voxels) splits the colon's core, as a passage 0.8 mm deep splits
// gca-colon-00020's: the centerline searches the core with corridors through it and finds the
// whole piece's route, from the truth mask and from the CT, with touching loops and fluid on
// the CT; and no contact is cut at it (seed 1 from the truth mask was, as a contact between
// the sides of two tubes, until contacts needed their arms to leave in opposite directions).
TEST(ContactsPhantom, StrictureIsCrossedOnCorridors)
{
    openvdb::initialize();
    for (uint64_t seed : {1, 2}) {
        runVariant({seed, 0, false, false, false, true});
        runVariant({seed, 2, true, false, true, true});
    }
}

} // namespace
