// Tests of the synthetic CT phantom (colon/phantom.h): geometry of the sizes, determinism,
// HU of each structure, and the ground truth (centerline, radii, folds, polyps, lumen
// mask, separations). Only the small size is generated; the anatomy alone is built for
// many seeds where the voxels are not needed.
#include "colon/phantom.h"
#include "volume/vec3.h"
#include "tests/colon/truth_arc.h"
#include "tests/shapes/test_shapes.h"
#include "colon/phantom_anatomy.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace flyover;
namespace ph = flyover::phantom;

constexpr uint64_t SEED = 1;
constexpr double NOISE_HU = 15.0;

std::string describe(PhantomSize size, uint64_t seed)
{
    std::ostringstream s;
    s << "phantom size=" << phantomSizeName(size) << " seed=" << seed;
    return s.str();
}

const Phantom& smallPhantom()
{
    static const Phantom phantom = makePhantom({PhantomSize::Small, SEED, NOISE_HU});
    return phantom;
}

const ph::PhantomAnatomy& smallAnatomy()
{
    static const ph::PhantomAnatomy anatomy = ph::buildPhantomAnatomy(SEED);
    return anatomy;
}

using test::nearestVoxel;

template <typename T>
T sampleNearest(const Image3<T>& image, const Vec3d& worldMm)
{
    const auto v = nearestVoxel(image.geometry, worldMm);
    return image.at(v[0], v[1], v[2]);
}

/// Mean HU over the (2h+1)^3 voxels around the voxel nearest to a world point.
double meanHuAround(const Image3<int16_t>& ct, const Vec3d& worldMm, int64_t h)
{
    const auto c = nearestVoxel(ct.geometry, worldMm);
    double sum = 0;
    int count = 0;
    for (int64_t k = c[2] - h; k <= c[2] + h; ++k)
        for (int64_t j = c[1] - h; j <= c[1] + h; ++j)
            for (int64_t i = c[0] - h; i <= c[0] + h; ++i) {
                sum += ct.at(i, j, k);
                ++count;
            }
    return sum / count;
}

/// Distance (mm) from (x, y) to the skin outline, by fine sampling of its two half-ellipses.
double distanceToSkinMm(double x, double y)
{
    static const std::vector<std::array<double, 2>> outline = [] {
        std::vector<std::array<double, 2>> o(7200);
        for (std::size_t k = 0; k < o.size(); ++k) {
            const double t = 2.0 * PI * double(k) / double(o.size());
            const double s = std::sin(t);
            o[k] = {ph::BODY_HALF_WIDTH_MM * std::cos(t),
                    s * (s < 0 ? ph::BODY_ANTERIOR_DEPTH_MM : ph::BODY_POSTERIOR_DEPTH_MM)};
        }
        return o;
    }();
    double best = 1e300;
    for (const auto& q : outline)
        best = std::min(best, std::hypot(x - q[0], y - q[1]));
    return best;
}

// ---------------------------------------------------------------------------------------
// Sizes and parameters

TEST(PhantomSizeName, RoundTripsEverySize)
{
    for (PhantomSize size : {PhantomSize::Small, PhantomSize::Medium, PhantomSize::Full})
        EXPECT_EQ(parsePhantomSize(phantomSizeName(size)), size) << phantomSizeName(size);
}

TEST(PhantomSizeName, RejectsUnknownNameListingValidOnes)
{
    try {
        parsePhantomSize("huge");
        FAIL() << "parsePhantomSize(\"huge\") did not throw";
    } catch (const ParameterError& e) {
        const std::string message = e.what();
        for (const char* word : {"huge", "small", "medium", "full"})
            EXPECT_NE(message.find(word), std::string::npos) << "message: " << message;
    }
}

TEST(PhantomParams, RejectsNegativeNoise)
{
    EXPECT_THROW(makePhantom({PhantomSize::Small, SEED, -1.0}), ParameterError);
    EXPECT_THROW(makePhantom({PhantomSize::Small, SEED, std::nan("")}), ParameterError);
}

TEST(PhantomGeometry, SizesShareOneCentredFieldOfView)
{
    struct Expected {
        PhantomSize size;
        std::array<int64_t, 3> voxels;
        Vec3d spacingMm;
    };
    const Expected all[] = {
        {PhantomSize::Small, {160, 160, 150}, {2.5, 2.5, 2.5}},
        {PhantomSize::Medium, {256, 256, 250}, {1.5625, 1.5625, 1.5}},
        {PhantomSize::Full, {512, 512, 450}, {0.78125, 0.78125, 0.8333333}},
    };
    for (const Expected& e : all) {
        SCOPED_TRACE(describe(e.size, SEED));
        const ImageGeometry g = ph::phantomGeometry(e.size);
        EXPECT_EQ(g.size, e.voxels);
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(g.spacingMm[c], e.spacingMm[c], 1e-6) << "axis " << c;
            const double fovMm = double(g.size[std::size_t(c)]) * g.spacingMm[c];
            EXPECT_NEAR(fovMm, c < 2 ? 400.0 : 375.0, 1e-9) << "axis " << c;
            // Voxel centres symmetric about 0: the volume is centred on the world origin.
            const double last = g.worldFromIndex(Vec3d{double(g.size[0] - 1), double(g.size[1] - 1),
                                                       double(g.size[2] - 1)})[c];
            EXPECT_NEAR(g.originMm[c] + last, 0.0, 1e-9) << "axis " << c;
        }
        EXPECT_EQ(g.direction, identityMat3());
    }
    const Phantom& p = smallPhantom();
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    EXPECT_EQ(p.ct.geometry.size, ph::phantomGeometry(PhantomSize::Small).size);
    EXPECT_EQ(p.ct.geometry.originMm, ph::phantomGeometry(PhantomSize::Small).originMm);
    EXPECT_EQ(p.truthLumen.geometry.size, p.ct.geometry.size);
    EXPECT_EQ(p.ct.voxels.size(), std::size_t(160 * 160 * 150));
    EXPECT_EQ(p.truthLumen.voxels.size(), p.ct.voxels.size());
}

// ---------------------------------------------------------------------------------------
// Determinism

TEST(PhantomDeterminism, SameSeedGivesIdenticalVoxelsWhateverTheThreadCount)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& a = smallPhantom();
    Phantom b;
    tbb::task_arena oneThread(1);
    oneThread.execute([&] { b = makePhantom({PhantomSize::Small, SEED, NOISE_HU}); });
    EXPECT_TRUE(a.ct.voxels == b.ct.voxels);
    EXPECT_TRUE(a.truthLumen.voxels == b.truthLumen.voxels);
    ASSERT_EQ(a.truth.polyps.size(), b.truth.polyps.size());
    for (std::size_t i = 0; i < a.truth.polyps.size(); ++i)
        EXPECT_EQ(a.truth.polyps[i].centerMm, b.truth.polyps[i].centerMm);
    EXPECT_EQ(a.truth.lumenVolumeMl, b.truth.lumenVolumeMl);
}

TEST(PhantomDeterminism, OtherSeedChangesNoisePolypsAndPocketsNotTheColon)
{
    constexpr uint64_t OTHER = 2;
    SCOPED_TRACE(describe(PhantomSize::Small, OTHER));
    const Phantom& a = smallPhantom();
    const Phantom b = makePhantom({PhantomSize::Small, OTHER, NOISE_HU});
    EXPECT_FALSE(a.ct.voxels == b.ct.voxels);
    bool polypsDiffer = a.truth.polyps.size() != b.truth.polyps.size();
    for (std::size_t i = 0; !polypsDiffer && i < a.truth.polyps.size(); ++i)
        polypsDiffer = a.truth.polyps[i].centerMm != b.truth.polyps[i].centerMm;
    EXPECT_TRUE(polypsDiffer);
    EXPECT_TRUE(a.truth.centerlineMm == b.truth.centerlineMm);
    EXPECT_TRUE(a.truth.radiusMm == b.truth.radiusMm);

    const ph::PhantomAnatomy pa = ph::buildPhantomAnatomy(SEED), pb = ph::buildPhantomAnatomy(OTHER);
    bool pocketsDiffer = pa.gasPockets.size() != pb.gasPockets.size();
    for (std::size_t i = 0; !pocketsDiffer && i < pa.gasPockets.size(); ++i)
        pocketsDiffer = pa.gasPockets[i].centerMm != pb.gasPockets[i].centerMm;
    EXPECT_TRUE(pocketsDiffer);
}

// ---------------------------------------------------------------------------------------
// Intensities

TEST(PhantomHu, ColonCenterlineIsAir)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    for (std::size_t i = 0; i < p.truth.centerlineMm.size(); i += 7) {
        const double hu = sampleNearest(p.ct, p.truth.centerlineMm[i]);
        EXPECT_NEAR(hu, -1000.0, 6.0 * NOISE_HU) << "centerline point " << i;
    }
}

TEST(PhantomHu, TissuesHaveTheirValues)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    // Means over 5^3 or 3^3 voxels: the noise on the mean is 15/sqrt(125) or 15/sqrt(27) HU.
    EXPECT_NEAR(meanHuAround(p.ct, {-185, -185, 0}, 2), -1000.0, 5.0) << "outside air";
    EXPECT_NEAR(meanHuAround(p.ct, {0, -40, 150}, 2), 40.0, 5.0) << "soft tissue";
    EXPECT_NEAR(meanHuAround(p.ct, {0, -121.5, 0}, 1), -100.0, 10.0) << "subcutaneous fat";
    EXPECT_NEAR(meanHuAround(p.ct, {-85, 15, 152}, 2), -850.0, 5.0) << "right lung";
    EXPECT_NEAR(meanHuAround(p.ct, {85, 15, 152}, 2), -850.0, 5.0) << "left lung";
    // Mid-vertebral body (discs are centred every 32 mm from z = 0).
    EXPECT_NEAR(meanHuAround(p.ct, {0, ph::SPINE_CENTER_Y_MM, 16}, 1), 700.0, 15.0) << "vertebra";
    // Pericolic fat, 5 mm outside the wall of the descending colon.
    const ph::PhantomAnatomy& a = smallAnatomy();
    double sum = 0;
    int count = 0;
    for (std::size_t i = 0; i < a.centerlineMm.size(); i += 10)
        if (a.segment[i] == "descending") {
            const Vec3d q = a.centerlineMm[i] + a.normal[i] * (a.radiusMm[i] + ph::COLON_WALL_MM + 5.0);
            sum += sampleNearest(p.ct, q);
            ++count;
        }
    ASSERT_GT(count, 5);
    EXPECT_NEAR(sum / count, -100.0, 20.0) << "pericolic fat";
}

// ---------------------------------------------------------------------------------------
// Truth centerline and radii

TEST(PhantomCenterline, RunsRectumToCecumThroughTheSegmentsInOrder)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const PhantomTruth& t = smallPhantom().truth;
    const std::size_t n = t.centerlineMm.size();
    ASSERT_GT(n, 2u);
    ASSERT_EQ(t.radiusMm.size(), n);
    ASSERT_EQ(t.segment.size(), n);

    const std::vector<std::string> order = {"rectum", "sigmoid", "descending", "transverse", "ascending", "cecum"};
    std::vector<std::string> runs;
    for (const std::string& s : t.segment)
        if (runs.empty() || runs.back() != s)
            runs.push_back(s);
    EXPECT_EQ(runs, order);

    // Uniform 1 mm arc step; length of a real colon.
    for (std::size_t i = 1; i < n; ++i)
        ASSERT_NEAR(distance(t.centerlineMm[i - 1], t.centerlineMm[i]), 1.0, 1e-3) << "point " << i;
    const double lengthMm = double(n - 1);
    EXPECT_GE(lengthMm, 1200.0);
    EXPECT_LE(lengthMm, 1500.0);

    // The rectum starts at the lowest point, in the midline; then the anatomy by side.
    double zMin = 1e300;
    for (const Vec3d& c : t.centerlineMm)
        zMin = std::min(zMin, c.z);
    EXPECT_NEAR(t.centerlineMm.front().z, zMin, 0.5);
    std::map<std::string, Vec3d> mean;
    std::map<std::string, int> count;
    for (std::size_t i = 0; i < n; ++i) {
        mean[t.segment[i]] += t.centerlineMm[i];
        ++count[t.segment[i]];
    }
    for (auto& [name, m] : mean)
        m = m / count[name];
    EXPECT_LT(std::abs(t.centerlineMm.front().x), 10.0) << "rectum off the midline";
    EXPECT_LT(std::abs(mean["rectum"].x), 10.0);
    EXPECT_GT(mean["sigmoid"].x, 20.0) << "sigmoid should loop to the patient's left (+x)";
    EXPECT_GT(mean["descending"].x, 80.0) << "descending colon on the left flank";
    EXPECT_LT(mean["ascending"].x, -80.0) << "ascending colon on the right flank";
    EXPECT_LT(mean["transverse"].y, -30.0) << "transverse colon anterior";
    EXPECT_GT(mean["transverse"].z, mean["descending"].z) << "transverse colon on top";
    // Transverse crosses from left to right.
    const auto first = std::find(t.segment.begin(), t.segment.end(), "transverse") - t.segment.begin();
    const auto last = std::find(t.segment.begin(), t.segment.end(), "ascending") - t.segment.begin() - 1;
    EXPECT_GT(t.centerlineMm[std::size_t(first)].x, 80.0);
    EXPECT_LT(t.centerlineMm[std::size_t(last)].x, -80.0);
    // Cecum: the blind end at the bottom right, below the transverse colon.
    EXPECT_LT(t.centerlineMm.back().x, -60.0);
    EXPECT_LT(t.centerlineMm.back().z, mean["transverse"].z - 100.0);
}

TEST(PhantomCenterline, RadiusWithinAnatomicalRanges)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const PhantomTruth& t = smallPhantom().truth;
    for (std::size_t i = 0; i < t.radiusMm.size(); ++i) {
        ASSERT_GE(t.radiusMm[i], 12.0) << "point " << i;
        ASSERT_LE(t.radiusMm[i], 28.0) << "point " << i;
    }
    std::map<std::string, std::pair<double, int>> mean;
    for (std::size_t i = 0; i < t.radiusMm.size(); ++i) {
        mean[t.segment[i]].first += t.radiusMm[i];
        ++mean[t.segment[i]].second;
    }
    const std::map<std::string, std::pair<double, double>> expected = {
        {"rectum", {20, 25}},     {"sigmoid", {12, 16}},   {"descending", {15, 18}},
        {"transverse", {20, 25}}, {"ascending", {22, 25}}, {"cecum", {25, 28}}};
    for (const auto& [name, range] : expected) {
        const double m = mean[name].first / std::max(1, mean[name].second);
        EXPECT_GE(m, range.first) << name;
        EXPECT_LE(m, range.second) << name;
    }
}

TEST(PhantomColon, NonAdjacentWallsStayFifteenMillimetresApart)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const PhantomTruth& t = smallPhantom().truth;
    const std::size_t n = t.centerlineMm.size();
    double worst = 1e300;
    std::size_t wi = 0, wj = 0;
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = i + 101; j < n; ++j) {  // > 100 mm apart along the colon
            const double gap = distance(t.centerlineMm[i], t.centerlineMm[j]) - t.radiusMm[i] - t.radiusMm[j] -
                               2.0 * ph::COLON_WALL_MM;
            if (gap < worst) {
                worst = gap;
                wi = i;
                wj = j;
            }
        }
    EXPECT_GE(worst, 15.0) << "outer walls at arc " << wi << " and " << wj << " mm";
    EXPECT_NEAR(ph::colonSelfClearance(smallAnatomy()).gapMm, worst, 1e-9);
}

TEST(PhantomColon, BendsAreWiderThanTheTube)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const ph::PhantomAnatomy& a = smallAnatomy();
    for (std::size_t i = 1; i + 1 < a.centerlineMm.size(); ++i) {
        const double curvature = length(a.tangent[i + 1] - a.tangent[i - 1]) / 2.0;
        ASSERT_LT(curvature * (a.radiusMm[i] + ph::COLON_WALL_MM), 1.0)
            << "bend radius " << 1.0 / curvature << " mm at arc " << i << " mm";
    }
}

TEST(PhantomColon, StaysInsideTheBodyAwayFromSkinAndImageBorder)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const PhantomTruth& t = smallPhantom().truth;
    for (std::size_t i = 0; i < t.centerlineMm.size(); i += 4) {
        const Vec3d& c = t.centerlineMm[i];
        const double outer = t.radiusMm[i] + ph::COLON_WALL_MM;
        ASSERT_LT(ph::bodySignedDistanceMm(c.x, c.y), 0.0) << "point " << i;
        ASSERT_GE(distanceToSkinMm(c.x, c.y) - outer, 15.0) << "point " << i;
        ASSERT_LE(std::abs(c.z) + outer, 187.5 - 10.0) << "point " << i;
    }
}

TEST(PhantomFolds, SpacingSizeAndCoverage)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const ph::PhantomAnatomy& a = smallAnatomy();
    ASSERT_GT(a.folds.size(), 20u);
    const auto sigmoidStart = std::find(a.segment.begin(), a.segment.end(), "sigmoid") - a.segment.begin();
    EXPECT_GT(a.folds.front().arcMm, double(sigmoidStart)) << "no folds in the rectum";
    EXPECT_LT(a.folds.back().arcMm, a.lengthMm() - a.radiusMm.back());
    for (std::size_t k = 0; k < a.folds.size(); ++k) {
        const ph::HaustralFold& f = a.folds[k];
        SCOPED_TRACE("fold " + std::to_string(k));
        if (k > 0) {
            EXPECT_GE(f.arcMm - a.folds[k - 1].arcMm, 25.0);
            EXPECT_LE(f.arcMm - a.folds[k - 1].arcMm, 40.0);
        }
        EXPECT_GE(f.thicknessMm, 3.0);
        EXPECT_LE(f.thicknessMm, 5.0);
        EXPECT_GE(f.depthMm / f.tubeRadiusMm, 0.25);
        EXPECT_LE(f.depthMm / f.tubeRadiusMm, 0.40);
        const double coverage = 2.0 * f.halfSectorRad / (2.0 * PI);
        EXPECT_NEAR(coverage, 2.0 / 3.0, 0.05);
    }
}

TEST(PhantomFolds, FoldVoxelsAreTissueNotLumen)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    const ph::PhantomAnatomy& a = smallAnatomy();
    const ImageGeometry& g = p.ct.geometry;
    int inFold = 0;
    double huSum = 0;
    for (const ph::HaustralFold& f : a.folds) {
        const auto c = std::size_t(f.index);
        const Vec3d centre = a.centerlineMm[c];
        const auto lo = nearestVoxel(g, centre - Vec3d{1, 1, 1} * (f.tubeRadiusMm + 3));
        const auto hi = nearestVoxel(g, centre + Vec3d{1, 1, 1} * (f.tubeRadiusMm + 3));
        for (int64_t k = lo[2]; k <= hi[2]; ++k)
            for (int64_t j = lo[1]; j <= hi[1]; ++j)
                for (int64_t i = lo[0]; i <= hi[0]; ++i) {
                    const Vec3d q = g.worldFromIndex(Vec3d{double(i), double(j), double(k)});
                    const double along = dot(q - centre, a.tangent[c]);
                    const double rho = length(q - centre - a.tangent[c] * along);
                    if (std::abs(along) > 3.0 || rho > f.tubeRadiusMm - 0.5)
                        continue;  // keep to the fold's own cross-section, inside the tube
                    if (f.signedDistanceMm(q, centre, a.tangent[c], a.normal[c], a.binormal[c]) > -0.3)
                        continue;
                    ++inFold;
                    huSum += p.ct.at(i, j, k);
                    EXPECT_EQ(p.truthLumen.at(i, j, k), 0) << "fold at arc " << f.arcMm << " voxel " << i
                                                           << "," << j << "," << k;
                }
    }
    ASSERT_GT(inFold, 30) << "fold voxels sampled";
    EXPECT_GT(huSum / inFold, -400.0) << "fold voxels should be mostly soft tissue";
}

// ---------------------------------------------------------------------------------------
// Polyps

TEST(PhantomPolyps, CountSizeAndPlacementForManySeeds)
{
    for (uint64_t seed = 1; seed <= 20; ++seed) {
        SCOPED_TRACE(describe(PhantomSize::Small, seed));
        const ph::PhantomAnatomy a = ph::buildPhantomAnatomy(seed);
        const auto& polyps = a.polyps;
        ASSERT_GE(polyps.size(), 6u);
        ASSERT_LE(polyps.size(), 10u);
        double rMin = 1e9, rMax = 0;
        int between = 0;
        for (std::size_t k = 0; k < polyps.size(); ++k) {
            const PhantomPolyp& q = polyps[k];
            SCOPED_TRACE("polyp " + std::to_string(k));
            rMin = std::min(rMin, q.radiusMm);
            rMax = std::max(rMax, q.radiusMm);
            EXPECT_GE(q.radiusMm, 3.0);
            EXPECT_LE(q.radiusMm, 12.0);
            EXPECT_GE(q.arcMm, 60.0);
            EXPECT_LE(q.arcMm, a.lengthMm() - 60.0);
            if (k > 0) {
                EXPECT_GE(q.arcMm - polyps[k - 1].arcMm, 40.0);
            }
            const auto i = std::size_t(std::lround(q.arcMm));
            EXPECT_LE(q.radiusMm, 0.5 * a.radiusMm[i] + 1e-9);
            // Centred on the lumen wall, outward from the centerline.
            EXPECT_NEAR(length(q.outwardDir), 1.0, 1e-9);
            EXPECT_NEAR(dot(q.outwardDir, a.tangent[i]), 0.0, 1e-9);
            EXPECT_NEAR(distance(q.centerMm, a.centerlineMm[i]), a.radiusMm[i], 1e-9);
            if (q.betweenFolds) {
                ++between;
                for (const ph::HaustralFold& f : a.folds)
                    EXPECT_GE(std::abs(f.arcMm - q.arcMm), q.radiusMm + 0.5 * f.thicknessMm);
            }
        }
        EXPECT_EQ(rMin, 3.0);
        EXPECT_GE(rMax, 10.0);
        EXPECT_GE(between, 3);
    }
}

TEST(PhantomPolyps, AreSoftTissueOutsideTheLumen)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    const ImageGeometry& g = p.ct.geometry;
    ASSERT_EQ(p.truth.polyps.size(), smallAnatomy().polyps.size());
    for (const PhantomPolyp& q : p.truth.polyps) {
        SCOPED_TRACE("polyp radius " + std::to_string(q.radiusMm) + " at arc " + std::to_string(q.arcMm));
        EXPECT_EQ(sampleNearest(p.truthLumen, q.centerMm), 0);
        // Voxels of the half protruding into the lumen, a voxel inside its surface.
        double sum = 0;
        int count = 0;
        const auto lo = nearestVoxel(g, q.centerMm - Vec3d{1, 1, 1} * q.radiusMm);
        const auto hi = nearestVoxel(g, q.centerMm + Vec3d{1, 1, 1} * q.radiusMm);
        for (int64_t k = lo[2]; k <= hi[2]; ++k)
            for (int64_t j = lo[1]; j <= hi[1]; ++j)
                for (int64_t i = lo[0]; i <= hi[0]; ++i) {
                    const Vec3d v = g.worldFromIndex(Vec3d{double(i), double(j), double(k)});
                    if (distance(v, q.centerMm) > q.radiusMm - 2.5 || dot(v - q.centerMm, q.outwardDir) > 0)
                        continue;
                    EXPECT_EQ(p.truthLumen.at(i, j, k), 0);
                    sum += p.ct.at(i, j, k);
                    ++count;
                }
        if (count > 0) {
            EXPECT_GT(sum / count, -200.0);
        }
    }
}

// ---------------------------------------------------------------------------------------
// Lumen mask

TEST(PhantomLumen, MaskHoldsTheCenterlineAndMatchesItsVolume)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    const PhantomTruth& t = p.truth;
    const auto voxels = std::count(p.truthLumen.voxels.begin(), p.truthLumen.voxels.end(), uint8_t(1));
    ASSERT_GT(voxels, 0);
    const Vec3d s = p.ct.geometry.spacingMm;
    EXPECT_NEAR(t.lumenVolumeMl, double(voxels) * s.x * s.y * s.z / 1000.0, 1e-9);
    for (std::size_t i = 0; i < t.centerlineMm.size(); ++i)
        ASSERT_EQ(sampleNearest(p.truthLumen, t.centerlineMm[i]), 1) << "centerline point " << i;
    // Tube volume by Pappus (sum of pi r^2 ds) plus the two end caps; folds and polyps
    // take a few percent away.
    double tubeMm3 = 0;
    for (double r : t.radiusMm)
        tubeMm3 += PI * r * r;
    tubeMm3 += 2.0 / 3.0 * PI * (std::pow(t.radiusMm.front(), 3) + std::pow(t.radiusMm.back(), 3));
    EXPECT_GT(t.lumenVolumeMl, 0.85 * tubeMm3 / 1000.0);
    EXPECT_LT(t.lumenVolumeMl, 1.01 * tubeMm3 / 1000.0);
}

// ---------------------------------------------------------------------------------------
// Other gas: lungs and small-bowel pockets

/// 6-connected components of ct < -400 HU.
struct AirComponents {
    std::vector<int32_t> label;  // -1: not air
    std::vector<std::vector<std::size_t>> members;
};

AirComponents labelAir(const Image3<int16_t>& ct)
{
    const auto& n = ct.geometry.size;
    AirComponents out;
    out.label.assign(ct.voxels.size(), -1);
    std::vector<std::size_t> stack;
    for (std::size_t seed = 0; seed < ct.voxels.size(); ++seed) {
        if (ct.voxels[seed] >= -400 || out.label[seed] >= 0)
            continue;
        const auto id = int32_t(out.members.size());
        out.members.emplace_back();
        out.label[seed] = id;
        stack.push_back(seed);
        while (!stack.empty()) {
            const std::size_t v = stack.back();
            stack.pop_back();
            out.members.back().push_back(v);
            const auto i = int64_t(v % std::size_t(n[0]));
            const auto j = int64_t((v / std::size_t(n[0])) % std::size_t(n[1]));
            const auto k = int64_t(v / std::size_t(n[0] * n[1]));
            const int64_t d[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
            for (const auto& o : d) {
                const int64_t a = i + o[0], b = j + o[1], c = k + o[2];
                if (a < 0 || b < 0 || c < 0 || a >= n[0] || b >= n[1] || c >= n[2])
                    continue;
                const std::size_t w = ct.linearIndex(a, b, c);
                if (ct.voxels[w] < -400 && out.label[w] < 0) {
                    out.label[w] = id;
                    stack.push_back(w);
                }
            }
        }
    }
    return out;
}

TEST(PhantomOtherGas, LungsAndBowelGasAreClosedAndFarFromTheColon)
{
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    const Phantom& p = smallPhantom();
    const ImageGeometry& g = p.ct.geometry;
    const auto& n = g.size;
    const AirComponents air = labelAir(p.ct);

    // Voxels within 10 mm of the true lumen, and those within one voxel (26-neighbours).
    const double reachMm = 10.0;
    const auto reach = int64_t(std::ceil(reachMm / g.spacingMm.x));
    std::vector<uint8_t> nearLumen(p.ct.voxels.size(), 0), touchesLumen(p.ct.voxels.size(), 0);
    for (int64_t k = 0; k < n[2]; ++k)
        for (int64_t j = 0; j < n[1]; ++j)
            for (int64_t i = 0; i < n[0]; ++i) {
                if (!p.truthLumen.at(i, j, k))
                    continue;
                for (int64_t c = -reach; c <= reach; ++c)
                    for (int64_t b = -reach; b <= reach; ++b)
                        for (int64_t a = -reach; a <= reach; ++a) {
                            const Vec3d d{a * g.spacingMm.x, b * g.spacingMm.y, c * g.spacingMm.z};
                            if (length(d) > reachMm || i + a < 0 || j + b < 0 || k + c < 0 || i + a >= n[0] ||
                                j + b >= n[1] || k + c >= n[2])
                                continue;
                            nearLumen[p.ct.linearIndex(i + a, j + b, k + c)] = 1;
                            if (std::abs(a) <= 1 && std::abs(b) <= 1 && std::abs(c) <= 1)
                                touchesLumen[p.ct.linearIndex(i + a, j + b, k + c)] = 1;
                        }
            }

    const int32_t colon = air.label[p.ct.linearIndex(
        nearestVoxel(g, p.truth.centerlineMm.front())[0], nearestVoxel(g, p.truth.centerlineMm.front())[1],
        nearestVoxel(g, p.truth.centerlineMm.front())[2])];
    ASSERT_GE(colon, 0);
    const auto lumenVoxels = std::count(p.truthLumen.voxels.begin(), p.truthLumen.voxels.end(), uint8_t(1));
    EXPECT_GT(double(air.members[std::size_t(colon)].size()), 0.95 * double(lumenVoxels))
        << "the colon is one air component";

    const ph::PhantomAnatomy& a = smallAnatomy();
    const double voxelMl = g.spacingMm.x * g.spacingMm.y * g.spacingMm.z / 1000.0;
    int lungs = 0, pockets = 0;
    for (std::size_t id = 0; id < air.members.size(); ++id) {
        const auto& m = air.members[id];
        bool touchesBorder = false, nearColon = false;
        Vec3d centroid;
        double huSum = 0;
        for (std::size_t v : m) {
            const auto i = int64_t(v % std::size_t(n[0]));
            const auto j = int64_t((v / std::size_t(n[0])) % std::size_t(n[1]));
            const auto k = int64_t(v / std::size_t(n[0] * n[1]));
            touchesBorder = touchesBorder || i == 0 || j == 0 || k == 0 || i == n[0] - 1 || j == n[1] - 1 ||
                            k == n[2] - 1;
            nearColon = nearColon || nearLumen[v];
            centroid += g.worldFromIndex(Vec3d{double(i), double(j), double(k)});
            huSum += p.ct.voxels[v];
        }
        centroid = centroid / double(m.size());
        const bool inPlaneBorder = std::any_of(m.begin(), m.end(), [&](std::size_t v) {
            const auto i = int64_t(v % std::size_t(n[0]));
            const auto j = int64_t((v / std::size_t(n[0])) % std::size_t(n[1]));
            return i == 0 || j == 0 || i == n[0] - 1 || j == n[1] - 1;
        });
        // Partial-volume voxels at the tips of folds can leave a colon voxel or two
        // 6-disconnected from the rest of the lumen: they touch the true lumen.
        const bool colonFragment = m.size() < 4 && std::any_of(m.begin(), m.end(), [&](std::size_t v) {
            return touchesLumen[v] != 0;
        });
        if (inPlaneBorder || int32_t(id) == colon || colonFragment)
            continue;  // outside air, colon
        const double volumeMl = double(m.size()) * voxelMl;
        std::ostringstream where;
        where << "air component of " << volumeMl << " mL at (" << centroid.x << ", " << centroid.y << ", "
              << centroid.z << ")";
        SCOPED_TRACE(where.str());
        EXPECT_FALSE(touchesBorder);
        EXPECT_FALSE(nearColon) << "within 10 mm of the colon lumen";
        if (centroid.z > 100.0) {
            ++lungs;
            EXPECT_NEAR(volumeMl, a.lungs[0].volumeMl(), 0.05 * a.lungs[0].volumeMl());
            EXPECT_NEAR(huSum / double(m.size()), -850.0, 30.0);
        } else {
            ++pockets;
            EXPECT_GE(volumeMl, 1.0);
            EXPECT_LE(volumeMl, 8.0);
            // The analytic pocket it images: volume within the sampling error of 2.5 mm voxels.
            const ph::Ellipsoid* nearest = nullptr;
            for (const ph::Ellipsoid& e : a.gasPockets)
                if (!nearest || distance(e.centerMm, centroid) < distance(nearest->centerMm, centroid))
                    nearest = &e;
            ASSERT_NE(nearest, nullptr);
            EXPECT_LT(distance(nearest->centerMm, centroid), 2.0);
            EXPECT_NEAR(volumeMl, nearest->volumeMl(), 0.3 * nearest->volumeMl());
        }
    }
    EXPECT_EQ(lungs, 2);
    EXPECT_EQ(pockets, int(a.gasPockets.size()));
    EXPECT_GE(a.gasPockets.size(), 4u);
    EXPECT_LE(a.gasPockets.size(), 8u);
    for (const ph::Ellipsoid& e : a.gasPockets) {
        EXPECT_GE(e.volumeMl(), 1.0);
        EXPECT_LE(e.volumeMl(), 8.0);
    }
}

} // namespace

// ---------------------------------------------------------------------------------------
// Variants: tagged fluid, collapsed stretches, no colon

/// FNV-1a of a buffer's bytes (stable across platforms, unlike std::hash).
template <typename T>
uint64_t fnv1a(const std::vector<T>& v)
{
    uint64_t h = 1469598103934665603ull;
    const auto* p = reinterpret_cast<const unsigned char*>(v.data());
    for (std::size_t i = 0; i < v.size() * sizeof(T); ++i) {
        h ^= p[i];
        h *= 1099511628211ull;
    }
    return h;
}

TEST(PhantomVariants, DefaultPhantomBytesUnchanged_GoldenRegression)
{
    // Golden digests of the default small phantom, seed 1, taken before the variants existed:
    // other modules' tests depend on these voxels.
    SCOPED_TRACE(describe(PhantomSize::Small, SEED));
    EXPECT_EQ(fnv1a(smallPhantom().ct.voxels), 0xa217579875abf29cull);
    EXPECT_EQ(fnv1a(smallPhantom().truthLumen.voxels), 0xb47bcc64ee27050cull);
    EXPECT_TRUE(smallPhantom().truth.collapsed.empty());
    EXPECT_TRUE(smallPhantom().truth.fluidPools.empty());
    EXPECT_EQ(smallPhantom().truth.fluidVolumeMl, 0.0);
}

using test::nearestArcMm;

/// Voxels at least a voxel below their pool's level (along gravity: posterior supine,
/// anterior prone) are fluid (its HU within noise), at least a voxel above are air; both are
/// truth lumen, and the truth lumen is the colon's without fluid, voxel for voxel.
void expectFluidBelowFlatLevels(const PhantomParams& p, std::size_t pools, double downY, int64_t minFluidVoxels)
{
    const Phantom ph = makePhantom(p);
    ASSERT_EQ(ph.truth.fluidPools.size(), pools);
    for (const PhantomFluidPool& pool : ph.truth.fluidPools) {
        EXPECT_GE(pool.hu, 300.0);
        EXPECT_LE(pool.hu, 600.0);
        EXPECT_EQ(pool.downY, downY);
    }
    const auto& g = ph.ct.geometry;
    const double h = g.spacingMm.y;
    int64_t fluid = 0, air = 0, wrong = 0;
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                if (!ph.truthLumen.at(i, j, k)) continue;
                // Only voxels whose 26 neighbours are lumen (no wall partial volume).
                bool interior = true;
                for (int dk = -1; dk <= 1 && interior; ++dk)
                    for (int dj = -1; dj <= 1 && interior; ++dj)
                        for (int di = -1; di <= 1 && interior; ++di)
                            interior = ph.truthLumen.at(i + di, j + dj, k + dk) != 0;
                if (!interior) continue;
                const Vec3d w = g.worldFromIndex({double(i), double(j), double(k)});
                const double arc = nearestArcMm(ph.truth.centerlineMm, w);
                for (const PhantomFluidPool& pool : ph.truth.fluidPools) {
                    if (arc < pool.arcStartMm || arc > pool.arcEndMm) continue;
                    const double hu = ph.ct.at(i, j, k);
                    const double below = (w.y - pool.levelYMm) * downY;
                    if (below > h) {
                        ++fluid;
                        wrong += std::abs(hu - pool.hu) > 6 * NOISE_HU;
                    } else if (below < -h) {
                        ++air;
                        wrong += std::abs(hu - ph::AIR_HU) > 6 * NOISE_HU;
                    }
                }
            }
    EXPECT_GT(fluid, minFluidVoxels);
    EXPECT_GT(air, 2000);
    EXPECT_EQ(wrong, 0);
    EXPECT_GT(ph.truth.fluidVolumeMl, 0.025 * double(minFluidVoxels));
    EXPECT_LT(ph.truth.fluidVolumeMl, 0.2 * ph.truth.lumenVolumeMl);
    PhantomParams plain = p;
    plain.fluid = plain.prone = false;
    EXPECT_TRUE(makePhantom(plain).truthLumen.voxels == ph.truthLumen.voxels);
}

TEST(PhantomVariants, FluidLiesPosteriorOfFlatLevelsAndIsLumen)
{
    PhantomParams p{PhantomSize::Small, 2, NOISE_HU};
    p.fluid = true;
    SCOPED_TRACE(describe(p.size, p.seed) + " fluid");
    expectFluidBelowFlatLevels(p, 3, 1.0, 2000);
}

TEST(PhantomVariants, ProneFluidLiesAnteriorInTheSigmoidAndTransverseColon)
{
    for (uint64_t seed : {1u, 2u, 3u}) {
        PhantomParams p{PhantomSize::Small, seed, NOISE_HU};
        p.fluid = p.prone = true;
        SCOPED_TRACE(describe(p.size, p.seed) + " fluid prone");
        expectFluidBelowFlatLevels(p, 2, -1.0, 800);  // two smaller pools
        // The rectum, posterior in the pelvis, lies above the fluid: no pool reaches it; one
        // pool lies in the sigmoid, one in the transverse colon.
        const Phantom ph = makePhantom(p);
        const auto arcOf = [&](const char* segment) {
            const auto& names = ph.truth.segment;
            return double(std::find(names.begin(), names.end(), segment) - names.begin());
        };
        ASSERT_EQ(ph.truth.fluidPools.size(), 2u);
        EXPECT_GT(ph.truth.fluidPools[0].arcStartMm, 60.0);
        EXPECT_LT(ph.truth.fluidPools[0].arcStartMm, arcOf("descending"));
        EXPECT_GT(ph.truth.fluidPools[1].arcEndMm, arcOf("transverse"));
        EXPECT_LT(ph.truth.fluidPools[1].arcStartMm, arcOf("ascending"));
    }
    PhantomParams dry{PhantomSize::Small, 1, NOISE_HU};
    dry.prone = true;
    EXPECT_THROW(makePhantom(dry), ParameterError);
}

TEST(PhantomVariants, WideRectumIsTheWidestLumenAndKeepsEveryInvariant)
{
    for (bool redundant : {false, true}) {
        PhantomParams pp;
        pp.wideRectum = true;
        pp.redundant = redundant;
        pp.touching = redundant ? PHANTOM_MAX_CONTACTS : 2;
        const Phantom ph = makePhantom(pp);  // throws naming the invariant a wide rectum breaks
        const auto& r = ph.truth.radiusMm;
        double lowest = 1e9, rest = 0;
        for (std::size_t i = 0; i < r.size(); ++i) {
            if (i >= 15 && i <= 50) lowest = std::min(lowest, r[i]);
            if (i > 120) rest = std::max(rest, r[i]);
        }
        EXPECT_GE(lowest, 28.0) << "the rectum's radius over its lowest 50 mm";
        EXPECT_GT(lowest, rest) << "the rectum is the widest lumen";
        EXPECT_EQ(ph.truth.contacts.size(), std::size_t(pp.touching));
    }
}

TEST(PhantomVariants, CollapsedStretchesHaveNoLumen)
{
    for (uint64_t seed : {1u, 2u}) {
        PhantomParams p{PhantomSize::Small, seed, NOISE_HU};
        p.collapse = true;
        SCOPED_TRACE(describe(p.size, p.seed) + " collapse");
        const Phantom ph = makePhantom(p);
        ASSERT_FALSE(ph.truth.collapsed.empty());
        ASSERT_LE(ph.truth.collapsed.size(), 2u);
        for (const PhantomCollapse& c : ph.truth.collapsed) {
            EXPECT_GE(c.arcEndMm - c.arcStartMm, 20.0);
            EXPECT_LE(c.arcEndMm - c.arcStartMm, 40.0);
            for (const PhantomPolyp& polyp : ph.truth.polyps)
                EXPECT_TRUE(polyp.arcMm + polyp.radiusMm < c.arcStartMm || polyp.arcMm - polyp.radiusMm > c.arcEndMm);
        }
        // The truth centerline is the full path; no truth lumen voxel is nearest to a point
        // more than a voxel inside a collapsed stretch.
        EXPECT_EQ(ph.truth.centerlineMm.size(), ph::buildPhantomAnatomy(seed).centerlineMm.size());
        const auto& g = ph.truthLumen.geometry;
        int64_t inCollapse = 0;
        for (int64_t k = 0; k < g.size[2]; ++k)
            for (int64_t j = 0; j < g.size[1]; ++j)
                for (int64_t i = 0; i < g.size[0]; ++i) {
                    if (!ph.truthLumen.at(i, j, k)) continue;
                    const double arc = nearestArcMm(ph.truth.centerlineMm, g.worldFromIndex({double(i), double(j), double(k)}));
                    for (const PhantomCollapse& c : ph.truth.collapsed)
                        inCollapse += arc > c.arcStartMm + g.spacingMm.x && arc < c.arcEndMm - g.spacingMm.x;
                }
        EXPECT_EQ(inCollapse, 0);
    }
}

TEST(PhantomVariants, NoColonLeavesBodyLungsAndGas)
{
    PhantomParams p{PhantomSize::Small, SEED, NOISE_HU};
    p.colon = false;
    const Phantom ph = makePhantom(p);
    EXPECT_EQ(std::count(ph.truthLumen.voxels.begin(), ph.truthLumen.voxels.end(), uint8_t(1)), 0);
    EXPECT_EQ(ph.truth.lumenVolumeMl, 0.0);
    EXPECT_TRUE(ph.truth.centerlineMm.empty());
    // Where the colon's centerline ran there is now fat or soft tissue, not air.
    for (std::size_t i = 0; i < smallAnatomy().centerlineMm.size(); i += 50)
        EXPECT_GT(sampleNearest(ph.ct, smallAnatomy().centerlineMm[i]), -200) << "arc " << i << " mm";
}

TEST(PhantomPolyps, GivenDiametersArePlacedAndBadOnesRefused)
{
    PhantomParams p;
    p.polypDiametersMm = std::vector<double>{12.0, 7.0};
    const Phantom ph = makePhantom(p);
    ASSERT_EQ(ph.truth.polyps.size(), 2u);
    std::vector<double> d;
    for (const auto& q : ph.truth.polyps) d.push_back(2 * q.radiusMm);
    std::sort(d.begin(), d.end());
    EXPECT_DOUBLE_EQ(d[0], 7.0);
    EXPECT_DOUBLE_EQ(d[1], 12.0);
    p.polypDiametersMm = std::vector<double>{};
    EXPECT_TRUE(makePhantom(p).truth.polyps.empty());
    p.polypDiametersMm = std::vector<double>{40.0};
    try {
        makePhantom(p);
        ADD_FAILURE() << "a 40 mm polyp was accepted";
    } catch (const ParameterError& e) {
        EXPECT_NE(std::string(e.what()).find("polyp diameters"), std::string::npos) << e.what();
    }
}
