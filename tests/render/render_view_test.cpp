// GCC 12 warns (-Wmaybe-uninitialized) inside OpenMesh's PropertyT<Vec3f>::push_back, whose
// VectorT default constructor leaves components uninitialised on purpose. Pragma scope is by
// source location, so ignoring it around the includes silences only third-party code.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "render/render_view.h"

#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>
#pragma GCC diagnostic pop

namespace flyover {
namespace {

using test::makeBox;
using test::makeIcosphere;

/// Pixels where any channel differs by more than `threshold` (Embree's --compare-threshold idea).
int differingPixels(const RgbImage& a, const RgbImage& b, int threshold)
{
    EXPECT_EQ(a.width, b.width);
    EXPECT_EQ(a.height, b.height);
    int count = 0;
    for (std::size_t p = 0; p + 2 < a.rgb.size() && p + 2 < b.rgb.size(); p += 3) {
        bool differs = false;
        for (int c = 0; c < 3; ++c)
            differs = differs || std::abs(int(a.rgb[p + std::size_t(c)]) - int(b.rgb[p + std::size_t(c)])) > threshold;
        count += differs ? 1 : 0;
    }
    return count;
}

int hitCount(const HitImage& h)
{
    int n = 0;
    for (const float t : h.t) n += t >= 0.f ? 1 : 0;
    return n;
}

RenderOptions smallOptions(int w, int h, bool ost)
{
    RenderOptions o;
    o.widthPx = w;
    o.heightPx = h;
    o.ost = ost;
    return o;
}

/// The faces of `mesh` that face a pinhole at `eye`: exactly those OST keeps for rays from it.
TriMesh facesFacingEye(const TriMesh& mesh, const Vec3d& eye)
{
    return test::filterFaces(mesh, [&](const std::array<Vec3d, 3>& c) {
        return dot(c[0] - eye, test::faceNormal(c)) < 0.0;
    });
}

constexpr double R = 10.0;
const Vec3d CENTRE{2.0, -1.0, 5.0};

TEST(RenderView, CentrePixelDepthMatchesAnalyticHits)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 6, /*inward=*/true);
    const RayScene scene(mesh);
    const double d = 30.0, tol = 0.005 * R;
    Camera cam = lookAt(CENTRE + Vec3d{0, 0, d}, CENTRE, {0, 1, 0}, 60.0);
    const int size = 65;  // odd: the centre pixel's ray is the optical axis
    const std::size_t centrePixel = std::size_t(size / 2) * size + size / 2;
    SCOPED_TRACE("sphere r=" + std::to_string(R) + " at distance " + std::to_string(d));

    HitImage hits;
    renderView(scene, cam, smallOptions(size, size, true), &hits);
    EXPECT_NEAR(hits.t[centrePixel], d + R, tol);
    const int ostHits = hitCount(hits);

    renderView(scene, cam, smallOptions(size, size, false), &hits);
    EXPECT_NEAR(hits.t[centrePixel], d - R, tol);
    EXPECT_EQ(hitCount(hits), ostHits);  // same silhouette

    // Near plane between the two walls, no OST: the near wall is clipped away.
    cam.nearMm = d;
    renderView(scene, cam, smallOptions(size, size, false), &hits);
    EXPECT_NEAR(hits.t[centrePixel], d + R, tol);
    for (std::size_t i = 0; i < hits.t.size(); ++i) {
        if (hits.t[i] >= 0.f) {
            EXPECT_GE(hits.t[i], float(cam.nearMm)) << "pixel " << i;
        }
    }
}

TEST(RenderView, DepthIsAlongForwardAndTheNearClipIsAPlane)
{
    // A wall facing the camera at distance 10: every pixel has depth exactly 10, whatever its
    // angle off-axis, and a near plane just past it removes the wall everywhere.
    const TriMesh wall = test::buildMesh({{-100, -100, 0}, {100, -100, 0}, {100, 100, 0}, {-100, 100, 0}},
                                         {{0, 1, 2}, {0, 2, 3}}, false);
    const RayScene scene(wall);
    Camera cam = lookAt({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 80.0);
    const RenderOptions options = smallOptions(67, 45, true);  // odd sizes: partial edge tiles
    HitImage hits;
    renderView(scene, cam, options, &hits);
    ASSERT_EQ(hits.t.size(), std::size_t(67 * 45));
    for (std::size_t i = 0; i < hits.t.size(); ++i) {
        ASSERT_GE(hits.t[i], 0.f) << "pixel " << i;
        EXPECT_NEAR(hits.t[i], 10.0, 1e-4) << "pixel " << i;
        EXPECT_LT(hits.primId[i], 2u);
    }
    cam.nearMm = 9.99;
    renderView(scene, cam, options, &hits);
    EXPECT_EQ(hitCount(hits), 67 * 45);
    cam.nearMm = 10.01;
    renderView(scene, cam, options, &hits);
    EXPECT_EQ(hitCount(hits), 0);
    for (const uint32_t id : hits.primId) EXPECT_EQ(id, std::numeric_limits<uint32_t>::max());
}

TEST(RenderView, OstEqualsPlainRenderOfTheFacesFacingTheEye)
{
    struct Case {
        std::string name;
        TriMesh mesh;
        Vec3d eye;
    };
    const Case cases[] = {
        {"inward icosphere", makeIcosphere(CENTRE, R, 5, true), CENTRE + Vec3d{14, 21, 17}},
        {"inward box", makeBox({-10, -6, -4}, {8, 9, 12}, true), Vec3d{30, 25, 40}},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        const RayScene full(c.mesh);
        const TriMesh half = facesFacingEye(c.mesh, c.eye);
        ASSERT_GT(half.n_faces(), 0u);
        ASSERT_LT(half.n_faces(), c.mesh.n_faces());
        const RayScene farHalf(half);
        const Vec3d target = (full.boundsMin() + full.boundsMax()) * 0.5;
        const Camera cam = lookAt(c.eye, target, {0, 0, 1}, 50.0);
        RenderOptions options = smallOptions(64, 64, true);
        options.depthCue = true;  // the near and far walls of a sphere differ only in depth
        options.depthCueRangeMm = 20.0;

        const RgbImage ost = renderView(full, cam, options);
        options.ost = false;
        const RgbImage plainFar = renderView(farHalf, cam, options);
        const RgbImage plainFull = renderView(full, cam, options);

        const int budget = 64 * 64 / 100;  // < 1% of the pixels
        const int differing = differingPixels(ost, plainFar, 2);
        const int differingFromPlain = differingPixels(ost, plainFull, 2);
        RecordProperty(c.name + " differing", differing);
        RecordProperty(c.name + " differing from plain", differingFromPlain);
        EXPECT_LT(differing, budget);
        // The comparison has power: the plain render of the whole mesh shows the near walls.
        EXPECT_GT(differingFromPlain, 64 * 64 / 10);
    }
}

TEST(RenderView, DeterministicAcrossRunsAndThreadCounts)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 5, true);
    const RayScene scene(mesh);
    const Camera cam = lookAt(CENTRE + Vec3d{5, -25, 12}, CENTRE, {0, 0, 1}, 55.0);
    RenderOptions options = smallOptions(90, 70, true);
    options.supersample = 2;
    options.depthCue = true;

    HitImage hitsA, hitsB;
    const RgbImage a = renderView(scene, cam, options, &hitsA);
    const RgbImage b = renderView(scene, cam, options, &hitsB);
    EXPECT_EQ(differingPixels(a, b, 0), 0);
    EXPECT_EQ(a.rgb, b.rgb);
    EXPECT_EQ(hitsA.t, hitsB.t);
    EXPECT_EQ(hitsA.primId, hitsB.primId);

    RgbImage one, two;
    {
        const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
        one = renderView(scene, cam, options);
    }
    {
        const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
        two = renderView(scene, cam, options);
    }
    EXPECT_EQ(differingPixels(one, two, 0), 0);
    EXPECT_EQ(one.rgb, a.rgb);
}

TEST(RenderView, SupersamplingKeepsTheCentreRayHits)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 4, true);
    const RayScene scene(mesh);
    const Camera cam = lookAt(CENTRE + Vec3d{0, -30, 10}, CENTRE, {0, 0, 1}, 60.0);
    HitImage ref;
    const RgbImage single = renderView(scene, cam, smallOptions(48, 40, true), &ref);
    for (const int ss : {2, 3}) {
        RenderOptions options = smallOptions(48, 40, true);
        options.supersample = ss;
        HitImage hits;
        const RgbImage img = renderView(scene, cam, options, &hits);
        EXPECT_EQ(hits.t, ref.t) << "supersample " << ss;
        EXPECT_EQ(hits.primId, ref.primId) << "supersample " << ss;
        // Antialiasing changes edge pixels only.
        EXPECT_LT(differingPixels(img, single, 40), 48 * 40 / 10) << "supersample " << ss;
    }
}

TEST(RenderView, MissesShowTheBackgroundAndHitsTheTissueColour)
{
    const TriMesh empty;
    const RayScene nothing(empty);
    const Camera cam = lookAt({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 60.0);
    const RgbImage bg = renderView(nothing, cam, smallOptions(9, 7, true));
    ASSERT_EQ(bg.rgb.size(), std::size_t(9 * 7 * 3));
    for (std::size_t p = 0; p < bg.rgb.size(); p += 3) {
        EXPECT_EQ(bg.rgb[p], 20);
        EXPECT_EQ(bg.rgb[p + 1], 20);
        EXPECT_EQ(bg.rgb[p + 2], 28);
    }
    // Head-on lit tissue shows the full tissue colour (0.93, 0.62, 0.55) and is pinkish.
    const TriMesh wall = test::buildMesh({{-100, -100, 0}, {100, -100, 0}, {100, 100, 0}, {-100, 100, 0}},
                                         {{0, 1, 2}, {0, 2, 3}}, false);
    const RayScene scene(wall);
    const RgbImage lit = renderView(scene, cam, smallOptions(9, 9, true));
    const std::size_t centre = (4 * 9 + 4) * 3;
    EXPECT_NEAR(lit.rgb[centre], 0.93 * 255, 1.0);
    EXPECT_NEAR(lit.rgb[centre + 1], 0.62 * 255, 1.0);
    EXPECT_NEAR(lit.rgb[centre + 2], 0.55 * 255, 1.0);
}

TEST(RenderView, RejectsBadOptions)
{
    const TriMesh empty;
    const RayScene scene(empty);
    const Camera cam = lookAt({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 60.0);
    RenderOptions o = smallOptions(0, 10, true);
    EXPECT_THROW(renderView(scene, cam, o), ParameterError);
    o = smallOptions(10, 10, true);
    o.supersample = 0;
    EXPECT_THROW(renderView(scene, cam, o), ParameterError);
    Camera bad = cam;
    bad.nearMm = -1;
    EXPECT_THROW(renderView(scene, bad, smallOptions(10, 10, true)), ParameterError);
    bad = cam;
    bad.fovDeg = 180;
    EXPECT_THROW(renderView(scene, bad, smallOptions(10, 10, true)), ParameterError);
}

TEST(SideBySide, PlacesImagesWithADarkSeparator)
{
    RgbImage left{2, 3, std::vector<uint8_t>(2 * 3 * 3, 200)};
    RgbImage right{4, 3, std::vector<uint8_t>(4 * 3 * 3, 100)};
    const RgbImage both = sideBySide(left, right, 3);
    EXPECT_EQ(both.width, 2 + 3 + 4);
    EXPECT_EQ(both.height, 3);
    ASSERT_EQ(both.rgb.size(), std::size_t(9 * 3 * 3));
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 9; ++x)
            for (int c = 0; c < 3; ++c) {
                const int v = both.rgb[std::size_t((y * 9 + x) * 3 + c)];
                if (x < 2) EXPECT_EQ(v, 200);
                else if (x < 5) EXPECT_LT(v, 20);
                else EXPECT_EQ(v, 100);
            }
    RgbImage shorter{4, 2, std::vector<uint8_t>(4 * 2 * 3, 0)};
    EXPECT_THROW(sideBySide(left, shorter), ParameterError);
}

} // namespace
} // namespace flyover
