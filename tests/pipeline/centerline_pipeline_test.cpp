// Centerline on the synthetic phantoms, measured against their ground truth (the accuracy
// targets), and on the real TotalSegmentator colon label (mask-only input).
#include "colon/phantom.h"
#include "colon/centerline.h"
#include "volume/image_io.h"
#include "volume/ingest.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"

#include <gtest/gtest.h>
#include <openvdb/tools/Interpolation.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <vector>
#include <cstdio>
#include <string>

using namespace flyover;

namespace {

struct TruthProjection {
    double distanceMm;
    double arcMm;
};

TruthProjection projectOnTruth(const Vec3d& p, const std::vector<Vec3d>& line)
{
    TruthProjection best{std::numeric_limits<double>::max(), 0};
    double arc = 0;
    for (std::size_t i = 1; i < line.size(); ++i) {
        const Vec3d a = line[i - 1], ab = line[i] - a;
        const double len2 = dot(ab, ab);
        const double t = len2 > 0 ? std::clamp(dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
        const double d = distance(p, a + ab * t);
        if (d < best.distanceMm) best = {d, arc + t * std::sqrt(len2)};
        arc += std::sqrt(len2);
    }
    return best;
}

openvdb::FloatGrid::Ptr phantomSdf(const Phantom& ph)
{
    Image3<float> img;
    img.geometry = ph.ct.geometry;
    img.voxels.assign(ph.ct.voxels.begin(), ph.ct.voxels.end());
    auto hu = ingestImage(img, IngestParams{});
    return segmentLumen(*hu, SegmentParams{}).sdf;
}

/// What is measured on a phantom: distance to the true centerline (10 mm at each end
/// excluded), length, the sharpest turn between steps, the points outside the lumen.
struct Measured {
    double meanMm = 0, p95Mm = 0, maxMm = 0;
    double lengthMm = 0, trueLengthMm = 0;
    double maxTurnDeg = 0;
    int outsideLumen = 0;   ///< points off bridges where the SDF is not < 0
    double firstArcMm = 0, lastArcMm = 0;
    std::string describe() const
    {
        char b[320];
        std::snprintf(b, sizeof b,
                      "mean %.3f mm, p95 %.3f mm, max %.3f mm, length %.1f mm (truth %.1f), max turn %.1f deg, "
                      "%d points outside the lumen, ends at truth arcs %.1f and %.1f",
                      meanMm, p95Mm, maxMm, lengthMm, trueLengthMm, maxTurnDeg, outsideLumen, firstArcMm, lastArcMm);
        return b;
    }
};

Measured measure(const Centerline& cl, const std::vector<Vec3d>& truth, const openvdb::FloatGrid& sdf)
{
    Measured m;
    for (std::size_t i = 1; i < truth.size(); ++i) m.trueLengthMm += distance(truth[i], truth[i - 1]);
    m.lengthMm = cl.lengthMm();
    std::vector<double> d;
    const openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(sdf);
    for (const CenterlinePoint& p : cl.points) {
        if (!p.bridged &&
            !(sampler.wsSample(openvdb::Vec3d(p.positionMm.x, p.positionMm.y, p.positionMm.z)) < 0))
            ++m.outsideLumen;
        const TruthProjection pr = projectOnTruth(p.positionMm, truth);
        if (pr.arcMm < 10 || pr.arcMm > m.trueLengthMm - 10) continue;
        d.push_back(pr.distanceMm);
    }
    if (!d.empty()) {
        std::sort(d.begin(), d.end());
        for (double x : d) m.meanMm += x;
        m.meanMm /= double(d.size());
        m.p95Mm = d[std::size_t(0.95 * double(d.size() - 1))];
        m.maxMm = d.back();
    }
    for (std::size_t i = 1; i + 1 < cl.points.size(); ++i) {
        const Vec3d a = normalize(cl.points[i].positionMm - cl.points[i - 1].positionMm);
        const Vec3d b = normalize(cl.points[i + 1].positionMm - cl.points[i].positionMm);
        m.maxTurnDeg = std::max(m.maxTurnDeg, std::acos(std::clamp(dot(a, b), -1.0, 1.0)) * 180.0 / M_PI);
    }
    m.firstArcMm = projectOnTruth(cl.points.front().positionMm, truth).arcMm;
    m.lastArcMm = projectOnTruth(cl.points.back().positionMm, truth).arcMm;
    return m;
}

void expectIssueTargets(const Measured& m)
{
    EXPECT_LE(m.meanMm, 1.0);
    EXPECT_LE(m.p95Mm, 2.5);
    EXPECT_NEAR(m.lengthMm, m.trueLengthMm, 0.03 * m.trueLengthMm);
    EXPECT_LE(m.maxTurnDeg, 30.0);
    EXPECT_EQ(m.outsideLumen, 0);
    // Rectum -> cecum: starts near the truth's first point, ends near its last.
    EXPECT_LT(m.firstArcMm, 20.0);
    EXPECT_GT(m.lastArcMm, m.trueLengthMm - 20.0);
}

} // namespace

TEST(CenterlinePhantom, MeetsTheAccuracyTargetsOnSeveralSeedsAndSizes)
{
    openvdb::initialize();
    const struct {
        PhantomSize size;
        uint64_t seed;
    } cases[] = {{PhantomSize::Small, 1}, {PhantomSize::Small, 2}, {PhantomSize::Small, 3}, {PhantomSize::Medium, 4}};
    for (const auto& c : cases) {
        PhantomParams pp;
        pp.size = c.size;
        pp.seed = c.seed;
        SCOPED_TRACE(std::string("phantom ") + phantomSizeName(c.size) + ", seed " + std::to_string(c.seed));
        const Phantom ph = makePhantom(pp);
        const auto sdf = phantomSdf(ph);
        CenterlineReport report;
        const Centerline cl = extractCenterline(*sdf, CenterlineParams{}, nullptr, &report);
        ASSERT_GE(cl.points.size(), 100u);
        const Measured m = measure(cl, ph.truth.centerlineMm, *sdf);
        SCOPED_TRACE(m.describe());
        RecordProperty(std::string(phantomSizeName(c.size)) + "_seed" + std::to_string(c.seed), m.describe());
        std::printf("%s seed %llu: %s\n", phantomSizeName(c.size), (unsigned long long)c.seed, m.describe().c_str());
        expectIssueTargets(m);
        EXPECT_TRUE(report.bridges.empty());
        for (const CenterlinePoint& p : cl.points) EXPECT_FALSE(p.bridged);
    }
}

TEST(CenterlinePhantom, CollapsedPhantomGivesOnePathWithTheBridgeMarked)
{
    openvdb::initialize();
    PhantomParams pp;
    pp.seed = 1;
    pp.collapse = true;
    SCOPED_TRACE("phantom small, collapse, seed 1");
    const Phantom ph = makePhantom(pp);
    ASSERT_FALSE(ph.truth.collapsed.empty());
    const auto sdf = phantomSdf(ph);
    CenterlineReport report;
    const Centerline cl = extractCenterline(*sdf, CenterlineParams{}, nullptr, &report);
    const Measured m = measure(cl, ph.truth.centerlineMm, *sdf);
    SCOPED_TRACE(m.describe());
    std::printf("collapsed phantom: %s\n", m.describe().c_str());
    expectIssueTargets(m);

    // One bridge per collapse, and the bridged points span exactly the collapsed stretches (to
    // within the radius of the lumen that rounds off each piece's end).
    ASSERT_EQ(report.bridges.size(), ph.truth.collapsed.size());
    int used = 0;
    for (const CenterlinePieceInfo& piece : report.pieces) used += piece.used;
    EXPECT_EQ(used, int(ph.truth.collapsed.size()) + 1);
    std::vector<std::pair<double, double>> bridged;  // truth arcs of each bridged run
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        if (!cl.points[i].bridged) continue;
        const double arc = projectOnTruth(cl.points[i].positionMm, ph.truth.centerlineMm).arcMm;
        if (i == 0 || !cl.points[i - 1].bridged) bridged.push_back({arc, arc});
        bridged.back().second = arc;
    }
    ASSERT_EQ(bridged.size(), ph.truth.collapsed.size());
    for (std::size_t k = 0; k < bridged.size(); ++k) {
        const PhantomCollapse& c = ph.truth.collapsed[k];
        const double r = 15.0;  // > the lumen radius at the collapse
        EXPECT_LE(bridged[k].first, c.arcStartMm + 1.0) << "collapse " << c.arcStartMm << "-" << c.arcEndMm;
        EXPECT_GE(bridged[k].first, c.arcStartMm - r) << "collapse " << c.arcStartMm << "-" << c.arcEndMm;
        EXPECT_GE(bridged[k].second, c.arcEndMm - 1.0) << "collapse " << c.arcStartMm << "-" << c.arcEndMm;
        EXPECT_LE(bridged[k].second, c.arcEndMm + r) << "collapse " << c.arcStartMm << "-" << c.arcEndMm;
    }
}

TEST(CenterlineReal, TotalSegmentatorColonLabelGivesOneOrderedBridgedPath)
{
    // The real colon label (not inflated, 3 mm voxels) is broken in two pieces: one path runs
    // through both, bridged between them, every other point inside the label.
    openvdb::initialize();
    const std::string path = std::string(FLYOVER_SOURCE_DIR) + "/data/fixtures/real/example_seg.nii.gz";
    SCOPED_TRACE(path + ", label 20");
    auto source = openImage(path);
    SegmentParams sp;
    sp.maskLabel = 20;
    const LumenSegmentation seg = segmentFromMask(*source, sp);
    CenterlineReport report;
    const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{}, nullptr, &report);
    ASSERT_EQ(report.pieces.size(), 2u);
    EXPECT_TRUE(report.pieces[0].used && report.pieces[1].used);
    ASSERT_EQ(report.bridges.size(), 1u);
    const CenterlineBridgeInfo& b = report.bridges[0];
    std::printf("real colon label: %zu points, length %.1f mm; pieces %.1f mL (path %.1f mm) and %.1f mL (path %.1f mm); "
                "bridge gap %.1f mm, length %.1f mm\n",
                cl.points.size(), cl.lengthMm(), report.pieces[0].volumeMl, report.pieces[0].pathLengthMm,
                report.pieces[1].volumeMl, report.pieces[1].pathLengthMm, b.gapMm, b.lengthMm);
    // Sensible length: the two pieces' own paths plus the bridge, give or take the end trims.
    const double expected = report.pieces[0].pathLengthMm + report.pieces[1].pathLengthMm + b.lengthMm;
    EXPECT_NEAR(cl.lengthMm(), expected, 0.1 * expected);
    EXPECT_GT(cl.lengthMm(), 150.0);
    // One bridged run, inside the path (not at its ends), no longer than 1.3 x its gap.
    int runs = 0;
    std::size_t bridgedPoints = 0;
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        if (!cl.points[i].bridged) continue;
        ++bridgedPoints;
        if (i == 0 || !cl.points[i - 1].bridged) ++runs;
    }
    EXPECT_EQ(runs, 1);
    EXPECT_FALSE(cl.points.front().bridged);
    EXPECT_FALSE(cl.points.back().bridged);
    EXPECT_LE(b.lengthMm, 1.3 * b.gapMm);
    EXPECT_NEAR(double(bridgedPoints) * cl.stepMm, b.lengthMm, 3.0 * cl.stepMm);
    const openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(*seg.sdf);
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        const Vec3d& q = cl.points[i].positionMm;
        if (cl.points[i].bridged) continue;
        EXPECT_LT(sampler.wsSample(openvdb::Vec3d(q.x, q.y, q.z)), 0.0) << "point " << i << " off the bridge";
    }
}
