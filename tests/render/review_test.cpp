// Review views (render/review.h) on synthetic lumens: a wall patch under a shelf that the
// default fly-over pair cannot see but a rolled pair can; a closed-off pocket no view reaches.
#include "render/review.h"

#include "render/flyover_path.h"
#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cmath>

namespace flyover {
namespace {

using test::circleCenterline;

/// `extra`'s vertices and faces appended to `mesh`.
void append(TriMesh& mesh, const TriMesh& extra)
{
    const int offset = int(mesh.n_vertices());
    for (const auto v : extra.vertices()) mesh.add_vertex(extra.point(v));
    for (const auto f : extra.faces()) {
        std::vector<TriMesh::VertexHandle> vh;
        for (const auto v : extra.fv_range(f)) vh.emplace_back(v.idx() + offset);
        mesh.add_face(vh);
    }
}

constexpr double R_TORUS = 60.0, R_TUBE = 10.0;

/// A straight tube of radius 10 along z, 120 mm long, open at both ends, with its centerline
/// along the whole axis (so that no wall lies beyond the path's ends), and a shelf: a 1 mm
/// plate 30 mm long (along the tangent) inside the lumen at z = 60, 5 mm from the centerline on
/// the side camera 0 of the default pair looks at (-n), parallel to the image plane, reaching
/// from the wall on one side (-b) to 4.5 mm past the centerline. Its top hides the wall under
/// it from camera 0, and camera 1 sees that wall from behind.
struct ShelfTube {
    static constexpr std::size_t SHELF_AT = 60;  ///< centerline index of the shelf's middle
    Centerline line = makeLine();
    FlyoverAxes axes = flyoverAxes(line.points[SHELF_AT], 0.0);
    Vec3d origin = line.points[SHELF_AT].positionMm;

    static Centerline makeLine()
    {
        Centerline c;
        c.stepMm = 1.0;
        for (int i = 0; i <= 120; ++i) {
            CenterlinePoint p;
            p.positionMm = {0, 0, double(i)};
            p.radiusMm = R_TUBE;
            c.points.push_back(p);
        }
        computeTangentsAndNormals(c);
        return c;
    }

    /// World position of local (t, b, n) coordinates at the shelf.
    Vec3d at(double t, double b, double n) const { return origin + axes.t * t + axes.b * b + axes.n * n; }

    TriMesh mesh() const
    {
        std::vector<double> z, r;
        for (double v = 0; v <= 120.0 + 1e-9; v += 0.5) {
            z.push_back(v);
            r.push_back(R_TUBE);
        }
        TriMesh m = test::makeLathe(z, r, 128, /*inward=*/true);
        // The plate's faces point out of the plate, into the lumen (tissue seen from the lumen).
        // Box axes x, y, z are t, n, b: (t, n, b) is right-handed (b = t x n), so the mapping
        // keeps the winding.
        TriMesh plate = test::makeBox({-15.0, -5.5, -9.2}, {15.0, -4.5, 4.5}, /*inward=*/false);
        for (const auto v : plate.vertices()) {
            const auto p = plate.point(v);
            plate.set_point(v, test::toPoint(at(p[0], p[2], p[1])));
        }
        append(m, plate);
        return m;
    }

    /// True for a tube triangle under the shelf: between it and the wall, away from its ends.
    bool underShelf(const Vec3d& c) const
    {
        const Vec3d d = c - origin;
        const double t = dot(d, axes.t), b = dot(d, axes.b), n = dot(d, axes.n);
        return std::fabs(t) < 8.0 && b > -8.0 && b < 2.0 && n < -6.0;
    }
};

CoverageParams coverageParams()
{
    CoverageParams p;
    p.viewPx = 96;
    p.stepMm = 2.0;
    p.flythrough = false;
    return p;
}

TEST(Review, CentredRollPointsCameraZeroAtTheDirection)
{
    const Centerline line = circleCenterline(R_TORUS, R_TUBE);
    const CenterlinePoint& p = line.points[40];
    const FlyoverAxes axes = flyoverAxes(p, 0.0);
    for (const double deg : {0.0, 30.0, 100.0, -170.0}) {
        const double a = deg * PI / 180.0;
        const Vec3d d = axes.n * std::cos(a) + axes.b * std::sin(a) + axes.t * 3.0;  // any tangential part
        FlyoverParams fp;
        fp.rollDeg = centredRollDeg(p, d);
        const auto cams = flyoverCameras(p, fp, 10.0);
        const Vec3d dp = normalize(d - axes.t * dot(d, axes.t));
        EXPECT_NEAR(dot(cams[0].forward, dp), 1.0, 1e-9) << "direction at " << deg << " deg, roll " << fp.rollDeg;
        EXPECT_NEAR(dot(cams[1].forward, dp), -1.0, 1e-9);
    }
    EXPECT_THROW(centredRollDeg(p, p.tangent), InputError);
}

TEST(Review, RolledViewFindsTheWallUnderAShelf)
{
    const ShelfTube shelf;
    const TriMesh mesh = shelf.mesh();
    const RayScene scene(mesh);
    const CoverageParams cp = coverageParams();
    const std::vector<double> frame = flyoverFrameRadii(scene, shelf.line, cp.flyover);
    CoverageParams cpf = cp;
    cpf.frameRadiiMm = frame;
    const CoverageResult cov = computeCoverage(scene, shelf.line, cpf);
    const TriangleGeometry geo = triangleGeometry(scene);
    double hidden = 0, hiddenSeen = 0;
    for (std::size_t f = 0; f < geo.areaMm2.size(); ++f)
        if (shelf.underShelf(geo.centroidMm[f])) {
            hidden += geo.areaMm2[f];
            if (cov.flyover.seen[f]) hiddenSeen += geo.areaMm2[f];
        }
    SCOPED_TRACE("tube r=10 with a shelf at z = 60, 96 px every 2 mm");
    std::printf("shelf tube: fly-over %.4f, %zu missed regions; wall under the shelf %.1f mm^2, %.1f seen\n",
                cov.flyover.fraction, cov.flyover.missed.size(), hidden, hiddenSeen);
    ASSERT_GT(hidden, 60.0) << "the test's geometry: wall area under the shelf";
    ASSERT_LT(hiddenSeen, 0.2 * hidden) << "the default fly-over pair should not see under the shelf";
    ASSERT_LT(cov.flyover.fraction, 0.995);
    ASSERT_FALSE(cov.flyover.missed.empty());

    const ReviewResult review = planReview(scene, shelf.line, cp, frame, cov);
    double hiddenAfter = 0;
    for (std::size_t f = 0; f < geo.areaMm2.size(); ++f)
        if (shelf.underShelf(geo.centroidMm[f]) && review.withReview.seen[f]) hiddenAfter += geo.areaMm2[f];
    std::printf("with %zu review views (%zu candidates, %d rounds): %.4f; under the shelf %.1f of %.1f mm^2 seen\n",
                review.views.size(), review.candidatesEvaluated, review.rounds, review.withReview.fraction,
                hiddenAfter, hidden);
    RecordProperty("flyover", std::to_string(cov.flyover.fraction));
    RecordProperty("with_review", std::to_string(review.withReview.fraction));
    RecordProperty("views", int(review.views.size()));
    EXPECT_TRUE(review.targetReached);
    EXPECT_GE(review.withReview.fraction, 0.995);
    EXPECT_GT(hiddenAfter, 0.9 * hidden);
    ASSERT_FALSE(review.views.empty());
    EXPECT_LE(review.views.size(), 20u) << "a handful of views should do for one shelf";
    // Seen stays seen; the views' added areas account for the rise.
    double added = 0;
    for (const ReviewView& v : review.views) {
        std::printf("  %s at index %zu roll %.1f deg frame %.1f mm: +%.1f mm^2\n", v.kind.c_str(), v.centerlineIndex,
                    v.rollDeg, v.frameRadiusMm, v.addedAreaMm2);
        added += v.addedAreaMm2;
        EXPECT_GT(v.addedAreaMm2, 0.0);
        EXPECT_TRUE(v.cameras.size() == 1 || v.cameras.size() == 2) << v.kind;
        EXPECT_LT(v.centerlineIndex, shelf.line.points.size());
    }
    for (std::size_t f = 0; f < geo.areaMm2.size(); ++f)
        if (cov.flyover.seen[f]) {
            ASSERT_TRUE(review.withReview.seen[f]) << "triangle " << f;
        }
    EXPECT_NEAR(review.withReview.seenAreaMm2, cov.flyover.seenAreaMm2 + added, 1e-6 * cov.totalAreaMm2);
    // The first view is a pair turned (and raised) about the centerline at the shelf: the roll
    // is what reaches under it.
    EXPECT_NE(review.views.front().kind.find("_pair"), std::string::npos) << review.views.front().kind;
    EXPECT_NEAR(double(review.views.front().centerlineIndex), double(ShelfTube::SHELF_AT), 20.0);
    // The first view serves the fly-over's region under the shelf.
    ASSERT_GE(review.views.front().flyoverRegion, 0);
    const MissedRegion& served = cov.flyover.missed[std::size_t(review.views.front().flyoverRegion)];
    EXPECT_TRUE(shelf.underShelf(served.centroidMm) || distance(served.centroidMm, shelf.origin) < 15.0)
        << "first view serves the region at " << served.centroidMm.x << ", " << served.centroidMm.y << ", "
        << served.centroidMm.z;
    // The regions left are listed with the reason that the target was reached.
    ASSERT_EQ(review.unreached.size(), review.withReview.missed.size());
    for (const UnreachedRegion& u : review.unreached) EXPECT_NE(u.reason.find("not needed"), std::string::npos) << u.reason;
}

TEST(Review, ClosedOffPocketIsReportedAsOutOfReach)
{
    // A sealed pocket (an inward sphere of radius 4) 26 mm outside the torus wall: lumen no path
    // reaches, 1% of the area. No view can show it, so the target cannot be met.
    const Centerline line = circleCenterline(R_TORUS, R_TUBE);
    TriMesh mesh = test::makeTorus({0, 0, 0}, R_TORUS, R_TUBE, 256, 64, /*inward=*/true);
    const Vec3d pocket{R_TORUS + R_TUBE + 30.0, 0.0, 0.0};
    const TriMesh sphere = test::makeIcosphere(pocket, 4.0, 3, /*inward=*/true);
    append(mesh, sphere);
    double pocketArea = 0;
    for (const double a : triangleGeometry(RayScene(sphere)).areaMm2) pocketArea += a;
    const RayScene scene(mesh);
    const CoverageParams cp = coverageParams();
    const std::vector<double> frame = flyoverFrameRadii(scene, line, cp.flyover);
    const CoverageResult cov = computeCoverage(scene, line, cp);
    const ReviewResult review = planReview(scene, line, cp, frame, cov);
    std::printf("closed pocket: fly-over %.4f, with review %.4f, %zu views, %zu regions left\n", cov.flyover.fraction,
                review.withReview.fraction, review.views.size(), review.withReview.missed.size());
    EXPECT_FALSE(review.targetReached);
    EXPECT_LT(review.withReview.fraction, 0.995);
    ASSERT_EQ(review.unreached.size(), review.withReview.missed.size());
    bool found = false;
    for (const UnreachedRegion& u : review.unreached) {
        if (distance(u.region.centroidMm, pocket) > 1.0) continue;
        found = true;
        EXPECT_NEAR(u.region.areaMm2, pocketArea, 1e-6 * pocketArea);
        EXPECT_NE(u.reason.find("outside the lumen's reach"), std::string::npos) << u.reason;
        EXPECT_EQ(u.bestCandidateAreaMm2, 0.0);
    }
    EXPECT_TRUE(found) << "the pocket is not among the regions left";
}

TEST(Review, NoViewsWhenTheFlyoverAlreadyMeetsTheTarget)
{
    const Centerline line = circleCenterline(R_TORUS, R_TUBE);
    const TriMesh mesh = test::makeTorus({0, 0, 0}, R_TORUS, R_TUBE, 256, 64, /*inward=*/true);
    const RayScene scene(mesh);
    const CoverageParams cp = coverageParams();
    const std::vector<double> frame = flyoverFrameRadii(scene, line, cp.flyover);
    const CoverageResult cov = computeCoverage(scene, line, cp);
    ASSERT_GE(cov.flyover.fraction, 0.995);
    const ReviewResult review = planReview(scene, line, cp, frame, cov);
    EXPECT_TRUE(review.views.empty());
    EXPECT_TRUE(review.targetReached);
    EXPECT_EQ(review.withReview.seen, cov.flyover.seen);
    EXPECT_DOUBLE_EQ(review.withReview.fraction, cov.flyover.fraction);
}

TEST(Review, RejectsBadParametersAndSizes)
{
    const Centerline line = circleCenterline(R_TORUS, R_TUBE);
    const TriMesh mesh = test::makeTorus({0, 0, 0}, R_TORUS, R_TUBE, 64, 16, /*inward=*/true);
    const RayScene scene(mesh);
    CoverageParams cp = coverageParams();
    cp.viewPx = 16;
    const std::vector<double> frame(line.points.size(), 10.0);
    const CoverageResult cov = computeCoverage(scene, line, cp);
    ReviewParams bad;
    bad.targetFraction = 1.5;
    EXPECT_THROW(planReview(scene, line, cp, frame, cov, bad), ParameterError);
    bad = ReviewParams{};
    bad.elevationFactors = {0.0};
    EXPECT_THROW(planReview(scene, line, cp, frame, cov, bad), ParameterError);
    bad = ReviewParams{};
    bad.maxRounds = 0;
    EXPECT_THROW(planReview(scene, line, cp, frame, cov, bad), ParameterError);
    EXPECT_THROW(planReview(scene, line, cp, std::vector<double>(3, 10.0), cov), ParameterError);
    CoverageResult wrong = cov;
    wrong.flyover.seen.pop_back();
    EXPECT_THROW(planReview(scene, line, cp, frame, wrong), ParameterError);
    EXPECT_THROW(planReview(scene, Centerline{}, cp, frame, cov), InputError);
}

} // namespace
} // namespace flyover
