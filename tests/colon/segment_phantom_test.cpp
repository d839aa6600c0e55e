// Lumen segmentation (colon/segment.h) on the synthetic abdominal phantoms and their
// variants (colon/phantom.h: clean, tagged fluid, collapsed colon, no colon), measured against
// the phantom's truth lumen (air and fluid). Small size only (2.5 mm voxels), to keep CI fast.
#include "colon/phantom.h"
#include "tests/colon/truth_arc.h"
#include "colon/phantom_anatomy.h"
#include "volume/error.h"
#include "volume/ingest.h"
#include "colon/segment.h"

#include <gtest/gtest.h>
#include <openvdb/tools/Interpolation.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <sstream>
#include <string>

namespace {

using namespace flyover;
namespace ph = flyover::phantom;

std::string describeSegmentPhantom(const PhantomParams& p)
{
    std::ostringstream s;
    s << "phantom size=" << phantomSizeName(p.size) << " seed=" << p.seed << (p.fluid ? " fluid" : "")
      << (p.collapse ? " collapse" : "") << (p.colon ? "" : " no-colon");
    return s.str();
}

PhantomParams variant(uint64_t seed, bool fluid, bool collapse)
{
    PhantomParams p;
    p.size = PhantomSize::Small;
    p.seed = seed;
    p.fluid = fluid;
    p.collapse = collapse;
    return p;
}

openvdb::FloatGrid::Ptr huGrid(const Phantom& phantom)
{
    Image3<float> ct;
    ct.geometry = phantom.ct.geometry;
    ct.voxels.assign(phantom.ct.voxels.begin(), phantom.ct.voxels.end());
    return ingestImage(ct, IngestParams{});
}

struct Overlap {
    int64_t truth = 0, found = 0, both = 0;
    int64_t inLung = 0, inPocket = 0;  ///< segmented voxel centres inside a lung or a gas pocket
    double dice() const { return 2.0 * double(both) / double(truth + found); }
};

/// Dice of the level set (negative inside, sampled at the truth voxel centres) against the
/// truth lumen, and segmented voxels inside lungs or small-bowel gas.
Overlap overlap(const Phantom& phantom, const ph::PhantomAnatomy& anatomy, const openvdb::FloatGrid& sdf)
{
    Overlap o;
    const openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(sdf);
    const auto& g = phantom.truthLumen.geometry;
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                const bool t = phantom.truthLumen.at(i, j, k) != 0;
                const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                const bool s = sampler.wsSample(openvdb::Vec3d(w.x, w.y, w.z)) < 0.f;
                o.truth += t;
                o.found += s;
                o.both += t && s;
                if (!s) continue;
                for (const ph::Ellipsoid& lung : anatomy.lungs) o.inLung += lung.signedDistanceMm(w) < 0;
                for (const ph::Ellipsoid& pocket : anatomy.gasPockets) o.inPocket += pocket.signedDistanceMm(w) < 0;
            }
    return o;
}

std::string report(const LumenSegmentation& seg)
{
    std::ostringstream s;
    s << "lumen " << seg.lumenVolumeMl << " mL (mask " << seg.maskVolumeMl << " mL, fluid "
      << seg.fluidVolumeMl << " mL), gravity (" << seg.gravityDirection.x << ", "
      << seg.gravityDirection.y << ", " << seg.gravityDirection.z << ")\n";
    for (const AirComponent& c : seg.components)
        s << "  air " << c.reason << " " << c.volumeMl << " mL mean " << c.meanHu << " HU\n";
    for (const FluidPool& p : seg.fluidPools)
        s << "  fluid " << p.reason << " " << p.volumeMl << " mL mean " << p.meanHu << " HU level "
          << p.levelMm << " mm\n";
    for (const LumenPiece& p : seg.pieces)
        s << "  piece #" << p.order << " " << p.volumeMl << " mL at " << p.frameAngleDeg << " deg, centroid ("
          << p.centroidMm.x << ", " << p.centroidMm.y << ", " << p.centroidMm.z << ")\n";
    return s.str();
}

using test::nearestArcMm;

/// Volumes (mL) of the truth lumen's pieces in arc order: each truth voxel belongs to the
/// piece between the collapsed stretches that holds its nearest centerline point.
std::vector<double> truthPieceVolumesMl(const Phantom& phantom)
{
    const auto& t = phantom.truth;
    const auto& g = phantom.truthLumen.geometry;
    const double voxelMl = g.spacingMm.x * g.spacingMm.y * g.spacingMm.z / 1000.0;
    std::vector<double> volumes(t.collapsed.size() + 1, 0.0);
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                if (!phantom.truthLumen.at(i, j, k)) continue;
                const double arc = nearestArcMm(t.centerlineMm, g.worldFromIndex({double(i), double(j), double(k)}));
                std::size_t piece = 0;
                while (piece < t.collapsed.size() && arc > t.collapsed[piece].arcStartMm) ++piece;
                volumes[piece] += voxelMl;
            }
    return volumes;
}

struct Case {
    PhantomParams params;
    Phantom phantom;
    ph::PhantomAnatomy anatomy;
    openvdb::FloatGrid::Ptr hu;
};

Case makeCase(const PhantomParams& p)
{
    openvdb::initialize();
    Case c{p, makePhantom(p), ph::buildPhantomAnatomy(p.seed), nullptr};
    c.hu = huGrid(c.phantom);
    return c;
}

TEST(SegmentPhantom, CleanPhantomDiceAndNoLungOrSmallBowel)
{
    const Case c = makeCase(variant(1, false, false));
    SCOPED_TRACE(describeSegmentPhantom(c.params));
    const LumenSegmentation seg = segmentLumen(*c.hu, SegmentParams{});
    SCOPED_TRACE(report(seg));
    const Overlap o = overlap(c.phantom, c.anatomy, *seg.sdf);
    std::cout << "[ measure  ] clean phantom: Dice " << o.dice() << ", lumen " << seg.lumenVolumeMl
              << " mL (truth " << c.phantom.truth.lumenVolumeMl << " mL)\n";
    EXPECT_GE(o.dice(), 0.99);
    EXPECT_EQ(o.inLung, 0);
    EXPECT_EQ(o.inPocket, 0);
    EXPECT_EQ(seg.pieces.size(), 1u);
    for (const FluidPool& pool : seg.fluidPools) EXPECT_FALSE(pool.joined) << pool.volumeMl << " mL";
    // The level set's sub-voxel volume and the mask's voxel count agree within 1%.
    EXPECT_NEAR(seg.lumenVolumeMl, seg.maskVolumeMl, 0.01 * seg.maskVolumeMl);
    EXPECT_NEAR(seg.lumenVolumeMl, c.phantom.truth.lumenVolumeMl, 0.02 * c.phantom.truth.lumenVolumeMl);
    int lungs = 0, small = 0;
    for (const AirComponent& a : seg.components) {
        lungs += a.reason == "lung";
        small += a.reason == "small";
    }
    EXPECT_EQ(lungs, 2);
    EXPECT_EQ(small, int(c.anatomy.gasPockets.size()));
}

// Bug: the cleanse listed bone far from the colon (the spine, ~0.4 L on the full phantom) as a
// fluid pool "near the air" with reason "no level below air": it tested BoolTree::empty() on
// an intersection, which keeps nodes without active voxels. Only candidate components with a
// voxel within the air's partial-volume reach are pools now (and only those are looked at).
TEST(SegmentPhantom, BoneFarFromTheColonIsNoFluidPool)
{
    const Case c = makeCase(variant(1, false, false));
    SCOPED_TRACE(describeSegmentPhantom(c.params));
    const SegmentParams params;
    openvdb::Index64 above = 0;
    for (auto it = c.hu->tree().cbeginValueOn(); it; ++it) above += *it > params.fluidThresholdHu;
    ASSERT_GT(above, 1000u) << "the phantom should hold bone above the fluid threshold";
    const LumenSegmentation seg = segmentLumen(*c.hu, params);
    for (const FluidPool& pool : seg.fluidPools)
        ADD_FAILURE() << "a phantom without fluid lists a pool of " << pool.volumeMl << " mL, mean " << pool.meanHu
                      << " HU (" << pool.reason << ")";
    EXPECT_EQ(seg.fluidVolumeMl, 0.0);
}

/// Tagged fluid found below its levels, along the gravity the truth pools give (supine: +y,
/// prone: -y), and joined to the lumen, with no sheet left at the levels.
void expectFluidJoinsTheLumen(const PhantomParams& params)
{
    const Case c = makeCase(params);
    SCOPED_TRACE(describeSegmentPhantom(c.params) + (params.prone ? " prone" : "") + " stored " + params.orientation);
    ASSERT_FALSE(c.phantom.truth.fluidPools.empty());
    const double downY = c.phantom.truth.fluidPools.front().downY;
    const LumenSegmentation seg = segmentLumen(*c.hu, SegmentParams{});
    SCOPED_TRACE(report(seg));
    const Overlap o = overlap(c.phantom, c.anatomy, *seg.sdf);

    SegmentParams off;
    off.cleanse = false;
    const LumenSegmentation airOnly = segmentLumen(*c.hu, off);
    const Overlap oOff = overlap(c.phantom, c.anatomy, *airOnly.sdf);
    std::cout << "[ measure  ] fluid phantom: Dice " << o.dice() << " cleansed, " << oOff.dice()
              << " with --cleanse off; fluid " << seg.fluidVolumeMl << " mL (truth "
              << c.phantom.truth.fluidVolumeMl << " mL)\n";
    EXPECT_GE(o.dice(), 0.98);
    EXPECT_LT(oOff.dice(), o.dice() - 0.02);
    EXPECT_EQ(o.inLung, 0);
    EXPECT_EQ(o.inPocket, 0);
    EXPECT_EQ(seg.pieces.size(), 1u);

    // Supine: fluid settles posterior, +y in LPS; prone: anterior, -y.
    EXPECT_NEAR(seg.gravityDirection.y, downY, 1e-9);
    int joined = 0;  // pools of at least 1 mL (the rest: partial-volume fragments at a level)
    for (const FluidPool& p : seg.fluidPools) joined += p.joined && p.volumeMl >= 1.0;
    EXPECT_EQ(joined, int(c.phantom.truth.fluidPools.size()));
    for (const FluidPool& p : seg.fluidPools)
        if (p.joined && p.volumeMl >= 1.0) {
            // Each joined pool's level matches one of the truth levels within a voxel.
            double nearest = 1e9;
            for (const PhantomFluidPool& t : c.phantom.truth.fluidPools)
                nearest = std::min(nearest, std::abs(t.levelYMm * t.downY - p.levelMm));
            EXPECT_LT(nearest, 2.5) << "level " << p.levelMm << " mm";
        }
    EXPECT_NEAR(seg.fluidVolumeMl, c.phantom.truth.fluidVolumeMl, 0.25 * c.phantom.truth.fluidVolumeMl);
    EXPECT_NEAR(seg.lumenVolumeMl, seg.maskVolumeMl, 0.01 * seg.maskVolumeMl);

    // The same with one thread: cleansing does not depend on the thread count.
    LumenSegmentation one;
    tbb::task_arena single(1);
    single.execute([&] { one = segmentLumen(*c.hu, SegmentParams{}); });
    EXPECT_EQ(one.lumenVolumeMl, seg.lumenVolumeMl);
    EXPECT_EQ(one.fluidVolumeMl, seg.fluidVolumeMl);
    EXPECT_EQ(one.mask->activeVoxelCount(), seg.mask->activeVoxelCount());

    // No false wall or floating sheet at the air-fluid levels: truth lumen voxels within one
    // voxel of a level, away from the wall, are all inside.
    const openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(*seg.sdf);
    const auto& g = c.phantom.truthLumen.geometry;
    int64_t atLevel = 0, missed = 0;
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                if (!c.phantom.truthLumen.at(i, j, k)) continue;
                const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                bool nearLevel = false;
                for (const PhantomFluidPool& t : c.phantom.truth.fluidPools)
                    nearLevel = nearLevel || std::abs(w.y - t.levelYMm) <= g.spacingMm.y;
                if (!nearLevel) continue;
                // Away from the wall: all 26 neighbours are truth lumen too.
                bool interior = true;
                for (int dk = -1; dk <= 1 && interior; ++dk)
                    for (int dj = -1; dj <= 1 && interior; ++dj)
                        for (int di = -1; di <= 1 && interior; ++di)
                            interior = c.phantom.truthLumen.at(i + di, j + dj, k + dk) != 0;
                if (!interior) continue;
                ++atLevel;
                missed += sampler.wsSample(openvdb::Vec3d(w.x, w.y, w.z)) >= 0.f;
            }
    std::cout << "[ measure  ] " << atLevel << " lumen voxels at the levels, " << missed << " outside the lumen\n";
    EXPECT_GT(atLevel, 500);
    EXPECT_EQ(missed, 0);
}

TEST(SegmentPhantom, TaggedFluidJoinsTheLumen) { expectFluidJoinsTheLumen(variant(2, true, false)); }

// The prone scan of a CT colonography: the fluid pools anterior, and the scanner stores its
// rows and columns the other way round (DICOM head-first-prone: i towards the patient's
// right, j anterior; "RAS"). The levels are found along -y from the data alone.
TEST(SegmentPhantom, ProneFluidStoredAsAProneScanJoinsTheLumen)
{
    PhantomParams p = variant(2, true, false);
    p.prone = true;
    p.orientation = "RAS";
    expectFluidJoinsTheLumen(p);
}

TEST(SegmentPhantom, CollapsedColonKeepsEveryPieceInOrder)
{
    // Seed 2 collapses two stretches of the sigmoid: three pieces, the middle one about 60 mL.
    const Case c = makeCase(variant(2, false, true));
    SCOPED_TRACE(describeSegmentPhantom(c.params));
    ASSERT_EQ(c.phantom.truth.collapsed.size(), 2u);
    const LumenSegmentation seg = segmentLumen(*c.hu, SegmentParams{});
    SCOPED_TRACE(report(seg));
    const Overlap o = overlap(c.phantom, c.anatomy, *seg.sdf);
    std::cout << "[ measure  ] collapsed phantom: Dice " << o.dice() << ", " << seg.pieces.size() << " pieces:";
    for (const LumenPiece& p : seg.pieces) std::cout << " " << p.volumeMl << " mL";
    std::cout << "\n";
    EXPECT_GE(o.dice(), 0.98);
    EXPECT_EQ(o.inLung, 0);
    EXPECT_EQ(o.inPocket, 0);
    ASSERT_EQ(seg.pieces.size(), c.phantom.truth.collapsed.size() + 1);
    double smallest = 1e9;
    for (const LumenPiece& p : seg.pieces) smallest = std::min(smallest, p.volumeMl);
    EXPECT_LT(smallest, 80.0) << "the middle piece of sigmoid";
    // Frame order is anatomical order: the pieces match the truth's pieces in arc order.
    const std::vector<double> truthMl = truthPieceVolumesMl(c.phantom);
    for (std::size_t i = 0; i < seg.pieces.size(); ++i)
        EXPECT_NEAR(seg.pieces[i].volumeMl, truthMl[i], 0.05 * truthMl[i]) << "piece #" << i;
}

TEST(SegmentPhantom, FluidAndCollapseTogether)
{
    for (uint64_t seed : {3u, 6u}) {
        const Case c = makeCase(variant(seed, true, true));
        SCOPED_TRACE(describeSegmentPhantom(c.params));
        const LumenSegmentation seg = segmentLumen(*c.hu, SegmentParams{});
        SCOPED_TRACE(report(seg));
        const Overlap o = overlap(c.phantom, c.anatomy, *seg.sdf);
        std::cout << "[ measure  ] fluid + collapse seed " << seed << ": Dice " << o.dice() << ", "
                  << seg.pieces.size() << " pieces\n";
        EXPECT_GE(o.dice(), 0.98);
        EXPECT_EQ(o.inLung + o.inPocket, 0);
        EXPECT_EQ(seg.pieces.size(), c.phantom.truth.collapsed.size() + 1);
    }
}

TEST(SegmentPhantom, SeedKeepsEveryLargePiece)
{
    const Case c = makeCase(variant(2, false, true));
    SCOPED_TRACE(describeSegmentPhantom(c.params));
    SegmentParams p;
    p.seedMm = c.phantom.truth.centerlineMm[30];  // in the rectum
    const LumenSegmentation seg = segmentLumen(*c.hu, p);
    SCOPED_TRACE(report(seg));
    int seeded = 0;
    for (const AirComponent& a : seg.components) seeded += a.reason == "seed";
    EXPECT_EQ(seeded, 1);
    EXPECT_EQ(seg.pieces.size(), 3u);
    EXPECT_GE(overlap(c.phantom, c.anatomy, *seg.sdf).dice(), 0.98);

    // A seed in the lung keeps the lung (the user said so) ...
    p.seedMm = c.anatomy.lungs[0].centerMm;
    const LumenSegmentation lung = segmentLumen(*c.hu, p);
    EXPECT_GT(overlap(c.phantom, c.anatomy, *lung.sdf).inLung, 0);
    // ... and a seed in tissue is refused, saying where it is.
    p.seedMm = Vec3d{0, 65, 0};  // the spine
    try {
        segmentLumen(*c.hu, p);
        FAIL() << "expected InputError";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("seed (0.0, 65.0, 0.0) mm"), std::string::npos) << e.what();
    }
}

TEST(SegmentPhantom, NoColonGivesOneLineListingWhatWasFound)
{
    PhantomParams p = variant(1, false, false);
    p.colon = false;
    const Case c = makeCase(p);
    SCOPED_TRACE(describeSegmentPhantom(c.params));
    try {
        segmentLumen(*c.hu, SegmentParams{});
        FAIL() << "expected InputError";
    } catch (const InputError& e) {
        const std::string msg = e.what();
        std::cout << "[ message  ] " << msg << "\n";
        EXPECT_EQ(msg.find('\n'), std::string::npos);
        EXPECT_NE(msg.find("no air component qualifies as colon lumen"), std::string::npos);
        EXPECT_NE(msg.find("2 lung"), std::string::npos);
        EXPECT_NE(msg.find(std::to_string(c.anatomy.gasPockets.size()) + " small"), std::string::npos);
    }
}

} // namespace
