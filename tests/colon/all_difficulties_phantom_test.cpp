// The rectal tube and all the real-colon difficulties together, from the CT of the phantoms
// with truth (colon/phantom.h): the tube found whatever the voxel size (its air may not touch
// the outside air: a closed outer end, or a wall that partial volume closes at coarse voxels),
// the path from the rectum (the tube's tip as the rectum hint, as the centerline stage does)
// to the cecum, through every loop and never through a contact, with every contact found.
#include "colon/phantom.h"
#include "tests/colon/truth_arc.h"
#include "colon/centerline.h"
#include "colon/contacts.h"
#include "volume/error.h"
#include "volume/ingest.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace flyover;

/// The standard for a path against the truth.
constexpr double MAX_MEAN_ERROR_MM = 1.0;
constexpr double MAX_LENGTH_RATIO_OFF = 0.03;
/// The path's first point lies within this of the truth's rectum end (the anal verge): in
/// the rectum, whose radius there is about 20 mm.
constexpr double MAX_START_MM = 15.0;
/// The tube's tip found within two voxels (2.5 mm) of the truth's.
constexpr double MAX_TIP_ERROR_MM = 5.0;

struct Figures {
    double meanMm = 0, p95Mm = 0, startMm = 0, lengthRatio = 0, worstJumpMm = 0, closestContactRatio = 1e9;
    double firstArcMm = 0, lastArcMm = 0;
    std::size_t contactsFound = 0, cuts = 0;
    bool tubeFound = false;
    double tipErrorMm = 1e9;  ///< found tube tip to the truth's
};

/// CT (or the truth mask with fromMask) -> segment (with the rectal tube cut) -> contacts ->
/// centerline from the tube's tip, measured against the truth.
Figures runFromCt(const Phantom& ph, const std::string& label, bool fromMask = false)
{
    Figures f;
    Image3<float> image;
    const ImageGeometry& geometry = fromMask ? ph.truthLumen.geometry : ph.ct.geometry;
    image.geometry = geometry;
    if (fromMask) image.voxels.assign(ph.truthLumen.voxels.begin(), ph.truthLumen.voxels.end());
    else image.voxels.assign(ph.ct.voxels.begin(), ph.ct.voxels.end());
    LumenSegmentation seg = fromMask ? segmentFromMask(image, SegmentParams{})
                                     : segmentLumen(*ingestImage(image, IngestParams{}), SegmentParams{});
    f.tubeFound = seg.rectalTube.found;
    if (f.tubeFound && ph.truth.hasRectalTube)
        f.tipErrorMm = distance(seg.rectalTube.tipMm, ph.truth.rectalTube.tipMm());
    const ContactReport contacts = cutContacts(*seg.sdf, seg.mask.get(), ContactParams{});
    CenterlineParams cp;
    if (const auto tip = seg.sdf->getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META))
        cp.rectumMm = Vec3d{tip->value()[0], tip->value()[1], tip->value()[2]};
    const Centerline cl = extractCenterline(*seg.sdf, cp);
    if (cl.points.size() < 10) return f;

    const std::vector<Vec3d>& truth = ph.truth.centerlineMm;  // 1 mm samples, rectum first
    const double truthLength = double(truth.size() - 1);
    std::vector<double> err, arc;
    for (const CenterlinePoint& p : cl.points) {
        const double a = test::nearestArcMm(truth, p.positionMm);
        arc.push_back(a);
        err.push_back(distance(truth[std::size_t(a)], p.positionMm));
    }
    for (double e : err) f.meanMm += e / double(err.size());
    std::vector<double> sorted = err;
    std::sort(sorted.begin(), sorted.end());
    f.p95Mm = sorted[std::size_t(0.95 * double(sorted.size() - 1))];
    f.startMm = distance(cl.points.front().positionMm, truth.front());
    f.lengthRatio = cl.lengthMm() / truthLength;
    for (std::size_t i = 1; i < arc.size(); ++i) f.worstJumpMm = std::max(f.worstJumpMm, std::abs(arc[i] - arc[i - 1]));
    f.firstArcMm = arc.front();
    f.lastArcMm = arc.back();

    // Contacts: each truth contact has a cut one near it; the path keeps away from the
    // contact patch (midway between the two loops' axes): its nearest point there, over the
    // patch's distance to the nearer axis (a path through the contact gives about 0).
    for (const ContactInfo& c : contacts.contacts) f.cuts += c.cut;
    for (const PhantomContact& t : ph.truth.contacts) {
        double best = 1e9;
        for (const ContactInfo& c : contacts.contacts)
            if (c.cut) best = std::min(best, distance(c.positionMm, t.positionMm));
        f.contactsFound += best <= 3.0 * ph.ct.geometry.spacingMm.x + 0.5 * t.widthMm;
        const double toAxis = std::min(distance(t.positionMm, truth[std::size_t(std::lround(t.arcAMm))]),
                                       distance(t.positionMm, truth[std::size_t(std::lround(t.arcBMm))]));
        double nearest = 1e9;
        for (const CenterlinePoint& p : cl.points) nearest = std::min(nearest, distance(p.positionMm, t.positionMm));
        f.closestContactRatio = std::min(f.closestContactRatio, nearest / toAxis);
    }
    std::printf("[ %s ] tube %s (tip %.1f mm from the truth's); contacts %zu truth, %zu found, %zu cut; path %.1f mm vs truth %.1f mm (ratio %.3f), "
                "error mean %.2f p95 %.2f mm, starts %.1f mm from the truth rectum end (truth arc %.0f), ends at "
                "truth arc %.0f, largest jump along the truth %.1f mm, nearest to a contact %.2f of its distance "
                "to the axis\n",
                label.c_str(), f.tubeFound ? "found" : "not found", f.tipErrorMm, ph.truth.contacts.size(), f.contactsFound, f.cuts,
                cl.lengthMm(), truthLength, f.lengthRatio, f.meanMm, f.p95Mm, f.startMm, f.firstArcMm, f.lastArcMm,
                f.worstJumpMm, f.closestContactRatio);
    return f;
}

void expectStandard(const Figures& f, std::size_t truthContacts, double truthLengthMm)
{
    EXPECT_TRUE(f.tubeFound) << "the rectal tube is not found";
    EXPECT_LE(f.meanMm, MAX_MEAN_ERROR_MM) << "mean error to the truth centerline (mm)";
    EXPECT_NEAR(f.lengthRatio, 1.0, MAX_LENGTH_RATIO_OFF) << "path length / truth length";
    EXPECT_LE(f.startMm, MAX_START_MM) << "distance of the path's start from the truth's rectum end (mm)";
    EXPECT_GT(f.lastArcMm, truthLengthMm - 25.0) << "the path ends in the cecum (truth arc)";
    EXPECT_LE(f.worstJumpMm, 20.0) << "consecutive points jump along the truth arc: a shortcut";
    EXPECT_EQ(f.contactsFound, truthContacts) << "truth contacts with a cut contact near them";
    EXPECT_EQ(f.cuts, truthContacts) << "contacts cut vs truth";
    EXPECT_GT(f.closestContactRatio, 0.5) << "a path point near a contact's patch: through the contact";
}

/// A rectal-tube phantom from the CT (or its truth mask), against the standard, the tube's tip
/// within two voxels of the truth's when `checkTip`, and p95 within 3 mm (`p95Why`: what a
/// larger one meant). `premise` checks the phantom first.
void expectTubeCase(const PhantomParams& pp, const std::string& label, bool fromMask, bool checkTip,
                    const char* p95Why, const std::function<void(const Phantom&)>& premise = {})
{
    SCOPED_TRACE(label);
    const Phantom ph = makePhantom(pp);
    if (premise) premise(ph);
    const Figures f = runFromCt(ph, label, fromMask);
    expectStandard(f, ph.truth.contacts.size(), double(ph.truth.centerlineMm.size() - 1));
    if (checkTip) {
        EXPECT_LE(f.tipErrorMm, MAX_TIP_ERROR_MM) << "distance of the tube's tip from the truth's (mm)";
    }
    EXPECT_LE(f.p95Mm, 3.0) << "p95 distance to the truth (mm): " << p95Why;
}

// Former defect: at 2.5 mm voxels the tube's lumen is 1-3 voxels across and its wall
// closes it in the CT (partial volume, and the phantom's outer end is capped), so the colon's
// air never touches the outside and the tube was not looked for: the path started at the
// tube's outer end, 159 mm from the rectum.
TEST(RectalTubePhantom, FoundFromTheCtAtCoarseVoxels)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.rectalTube = true;
    for (uint64_t seed : {1, 2}) {
        pp.seed = seed;
        // The tube's closed tip (its cap of wall beyond the last axis point) is given to the
        // lumen with the rest of the tube inside the rectum: the path used to bend round it,
        // 9-13 mm off the truth for 60 mm (p95 5.3 mm).
        expectTubeCase(pp, "small (2.5 mm) rectal tube seed " + std::to_string(seed), false, false,
                       "the path bends round the tube's tip");
    }
}

// Defects: the tube was given back to the lumen only where the colon's *air* lay all round it
// (9 of 12 directions beyond its wall), before the tagged fluid was known. Supine, the fluid
// pools in the posterior rectum, next to the tube: it was filled over only part of its
// length, stayed a rod-shaped hole elsewhere (and a surface round it), and the path ran
// beside it, up to 18 mm off the rectum's axis (mean 1.13 / 1.06 mm, p95 7.8 / 7.6 mm, start
// 18.3 mm from the truth's on seeds 1 / 2). Now the fill looks for the lumen with the fluid.
// Then, where the tube crosses the air-fluid level at the anal verge (seeds 3, 7, 8, 10 of
// 12), the thin piece it is found in also held thin air by the level, its axis bins strayed
// up to 7 mm, the balls along them left specks of the tube's wall in the lumen, and the path
// kept 10 mm off the axis (seeds 3 / 7: mean 0.91 / 0.99, p95 4.2 / 4.9 mm); now the tube's
// own voxels are filled with their wall too, where the lumen or the tube lies all round them.
TEST(RectalTubePhantom, FilledWhereItLiesAgainstTaggedFluid)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.rectalTube = true;
    pp.fluid = true;
    for (uint64_t seed : {1, 2, 3, 7}) {
        pp.seed = seed;
        expectTubeCase(pp, "small (2.5 mm) rectal tube and tagged fluid, seed " + std::to_string(seed), false, false,
                       "the path runs beside the tube left in the rectum", [](const Phantom& ph) {
                           ASSERT_FALSE(ph.truth.fluidPools.empty());
                           EXPECT_LE(ph.truth.fluidPools.front().arcStartMm, 0.0) << "the first pool lies in the rectum";
                       });
    }
}

// Defect: on seed 12 the thin piece the tube is found in meets the rectum's air 18 mm below the
// tip, its last bin lies off the tube's core, and the run from there found no tube: it
// stopped a millimetre into the rectum, the tip was found 35 mm short, and the path ran round
// the rod left in the rectum (mean 1.07, p95 7.8 mm; with touching loops 1.11 / 7.5). The tube
// is now also followed from 10 mm before the piece's end, and that run taken when it reaches
// farther into the rectum.
TEST(RectalTubePhantom, FollowedFromInsideTheAnalCanalWhenThePieceEndsOffItsCore)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.rectalTube = true;
    pp.seed = 12;
    for (int touching : {0, 2}) {
        pp.touching = touching;
        expectTubeCase(pp, "small (2.5 mm) rectal tube, touching " + std::to_string(touching) + ", seed 12", false,
                       true, "the path bends round the tube left in the rectum");
    }
}

// Gas refluxed through an open ileocecal valve fills ~170 mm of terminal ileum, off the cecum's
// medial wall 50 mm above its end (the --ileal-reflux phantom): the ileum's end lies farther
// along the lumen from the rectum than the cecum's own end, and the path ran into the small
// bowel and skipped the cecum below the valve (seeds 1-3, with and without the rectal tube and
// fluid: mean 5.2-5.4 mm, p95 49 mm, length ratio 1.11). Now the narrow tube at the far end is
// plugged and the wide lumen's own end, 50 mm beyond the valve, is the path's end.
TEST(IlealRefluxPhantom, PathEndsInTheCecumNotInTheIleum)
{
    openvdb::initialize();
    struct Case {
        uint64_t seed;
        bool fluid;
        int touching;
        bool redundant;
    };
    for (const Case& c : {Case{1, false, 0, false}, Case{2, true, 0, false}, Case{3, true, 2, true}}) {
        PhantomParams pp;
        pp.seed = c.seed;
        pp.rectalTube = pp.ilealReflux = true;
        pp.fluid = c.fluid;
        pp.touching = c.touching;
        pp.redundant = c.redundant;
        expectTubeCase(pp,
                       "small (2.5 mm) ileal reflux and rectal tube, seed " + std::to_string(c.seed) +
                           (c.fluid ? ", fluid" : "") + (c.redundant ? ", redundant colon, 2 contacts" : ""),
                       false, false, "the path runs into the ileum", [](const Phantom& ph) {
                           ASSERT_FALSE(ph.truth.ileumMm.empty());
                           EXPECT_GT(ph.truth.ileumLumenVolumeMl, 30.0) << "the ileum holds gas";
                       });
    }
}

// Former defect: with two touching loops too (seeds 4-8), at 2.5 mm voxels, the tube was
// followed only part of the way into the rectum. From the CT a straight run from the anal
// canal started off the tube's axis (the thin piece's bin centroids stray by up to a voxel)
// and left the 2-voxel air core early: the tip was found 13-41 mm short (at the anal verge on
// seed 4), the tube's rod was left in the rectum, and the path ran 10-15 mm beside the axis
// for 60-80 mm (mean 1.04-1.26, p95 7.0-9.5 mm). From the truth mask the tube's 2 mm wall
// leaves out a whole side of its ring over several slices: followed to 12.6 mm short of its
// tip, the path bent round the hole left (mean 1.10-1.14, p95 7.8-8.3 mm). Now each run
// starts on the air core's centre, the followed axis is centred on the core, and inside the
// rectum's air a ring with a side missing is still the tube.

void touchingLoopsAndTube(uint64_t seed, bool fromMask)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.rectalTube = true;
    pp.touching = 2;
    pp.seed = seed;
    expectTubeCase(pp, std::string("small (2.5 mm) rectal tube, touching 2, ") + (fromMask ? "truth mask" : "CT") +
                           ", seed " + std::to_string(seed),
                   fromMask, true, "the path bends round the tube left in the rectum");
}

TEST(RectalTubePhantom, FollowedToItsTipFromTheCtWithTouchingLoops)
{
    touchingLoopsAndTube(4, false);
    touchingLoopsAndTube(5, false);
}

TEST(RectalTubePhantom, FollowedToItsTipFromTheMaskWithTouchingLoops) { touchingLoopsAndTube(4, true); }

// All the difficulties from the CT: two contacts, the redundant colon (about 2 m), the rectal
// tube, anisotropic slices. The real scans' 0.8 x 0.8 x 1.25 mm make a 500 x 500 x 300 phantom
// (minutes); the same anisotropy at twice the size, 1.6 x 1.6 x 2.5 mm, keeps each seed's test
// short (10-20 s).
void allDifficultiesFromTheCt(uint64_t seed, bool stricture = false)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.touching = 2;
    pp.redundant = true;
    pp.rectalTube = true;
    pp.stricture = stricture;
    pp.spacingMm = {1.6, 1.6, 2.5};
    pp.seed = seed;
    const std::string label = std::string("all difficulties") + (stricture ? " and a stricture" : "") +
                              ", 1.6 x 1.6 x 2.5 mm, seed " + std::to_string(seed);
    SCOPED_TRACE(label);
    const Phantom ph = makePhantom(pp);
    const Figures f = runFromCt(ph, label);
    expectStandard(f, 2, double(ph.truth.centerlineMm.size() - 1));
}

TEST(AllDifficultiesPhantom, FromTheCtSeed1) { allDifficultiesFromTheCt(1); }
TEST(AllDifficultiesPhantom, FromTheCtSeed2) { allDifficultiesFromTheCt(2); }
TEST(AllDifficultiesPhantom, FromTheCtSeed3) { allDifficultiesFromTheCt(3); }
// And a stricture: the core of the colon is split, so the route is searched on the core and
// corridors. Defect found with it: the phantom's stricture took lumen from loops within reach
// of it (seed 1: the path 11 mm off the truth over 100 mm of two other loops, mean 0.84 p95
// 3.61 mm; now 0.48 / 1.42 mm; PhantomStricture.ChangesTheLumenOnlyWhereItIs).
TEST(AllDifficultiesPhantom, WithStrictureFromTheCtSeed1) { allDifficultiesFromTheCt(1, true); }
TEST(AllDifficultiesPhantom, WithStrictureFromTheCtSeed2) { allDifficultiesFromTheCt(2, true); }
TEST(AllDifficultiesPhantom, WithStrictureFromTheCtSeed4) { allDifficultiesFromTheCt(4, true); }

} // namespace
