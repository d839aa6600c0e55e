#include "render/headlight_shade.h"
#include "render/render_view.h"

#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstring>
#include <random>
#include <cstdlib>
#include <limits>
#include <string>

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

// renderView shades a packet's lanes four at a time (SSE); each lane must be the scalar rule's
// float bit for bit, so images are the same bytes as with the one-lane code: random rays and
// normals of any length, zero normals (misses), parallel vectors (cosine rounding above 1),
// depths before the cue's start, infinite depths (misses) and NaN.
TEST(RenderView, ShadeOfFourLanesAtOnceIsTheScalarShadeBitForBit)
{
    constexpr int N = 4096;
    alignas(16) static float dx[N], dy[N], dz[N], nx[N], ny[N], nz[N], t[N], out[N];
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f), scale(0.01f, 100.0f), depth(0.0f, 300.0f);
    const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    for (int i = 0; i < N; ++i) {
        const float s = scale(rng);
        dx[i] = unit(rng);
        dy[i] = unit(rng);
        dz[i] = unit(rng);
        nx[i] = s * unit(rng);
        ny[i] = s * unit(rng);
        nz[i] = s * unit(rng);
        t[i] = depth(rng);
        switch (i % 8) {
        case 1: nx[i] = ny[i] = nz[i] = 0.0f; t[i] = inf; break;  // a miss
        case 2: nx[i] = 3.0f * dx[i]; ny[i] = 3.0f * dy[i]; nz[i] = 3.0f * dz[i]; break;  // parallel
        case 3: t[i] = 0.5f; break;  // before the cue's start
        case 4: if (i % 64 == 4) nx[i] = nan; break;
        case 5: if (i % 64 == 5) t[i] = nan; break;
        case 6: nx[i] *= 1e-20f; ny[i] *= 1e-20f; nz[i] *= 1e-20f; break;  // norms below 1e-30
        default: break;
        }
    }
    for (const float invCue : {0.0f, 1.0f / 70.0f}) {
        detail::headlightShadeLanes(dx, dy, dz, nx, ny, nz, t, N, invCue, 2.0f, out);
        int differing = 0, firstDiffering = -1;
        for (int i = 0; i < N; ++i) {
            const float expected = detail::headlightShade(dx[i], dy[i], dz[i], nx[i], ny[i], nz[i], t[i], invCue, 2.0f);
            if (std::memcmp(&expected, &out[i], sizeof(float)) != 0) {
                if (firstDiffering < 0) firstDiffering = i;
                ++differing;
            }
        }
        EXPECT_EQ(differing, 0) << "depth cue 1/" << (invCue > 0 ? 1.0f / invCue : 0.0f) << " mm: " << differing
                                << " of " << N << " lanes differ from the scalar shade, the first lane " << firstDiffering;
    }
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
        // Flat shading: the half mesh's border vertices would get other smooth normals.
        options.smoothShading = false;
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

TEST(RenderView, OstMethodsGiveTheSameHits)
{
    // The two-pass scheme (trace plain, retrace back-face lanes with the filter) is exact: it
    // returns what the filter alone returns, from outside, from inside, and with near planes
    // that start rays inside or outside the lumen.
    struct Case {
        std::string name;
        TriMesh mesh;
        Vec3d eye, target;
        double nearMm;
    };
    const Case cases[] = {
        {"sphere from outside", makeIcosphere(CENTRE, R, 5, true), CENTRE + Vec3d{14, 21, 17}, CENTRE, 0.0},
        {"sphere, near plane inside", makeIcosphere(CENTRE, R, 5, true), CENTRE + Vec3d{0, 0, 25}, CENTRE, 20.0},
        {"sphere from inside", makeIcosphere(CENTRE, R, 5, true), CENTRE + Vec3d{1, 2, 3}, CENTRE + Vec3d{0, 5, 0}, 0.0},
        {"torus from outside", test::makeTorus(CENTRE, 20.0, 6.0, 96, 32, true), CENTRE + Vec3d{5, -50, 40}, CENTRE, 0.0},
        {"torus, near plane crossing", test::makeTorus(CENTRE, 20.0, 6.0, 96, 32, true), CENTRE + Vec3d{20, 0, 12},
         CENTRE + Vec3d{20, 0, 0}, 9.0},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        const RayScene scene(c.mesh);
        Camera cam = lookAt(c.eye, c.target, {0, 1, 0}, 70.0);
        cam.nearMm = c.nearMm;
        HitImage reference;
        RenderOptions o = smallOptions(61, 47, true);
        o.ostMethod = OstMethod::Filter;
        traceHits(scene, cam, o, reference);
        ASSERT_GT(hitCount(reference), 0);
        for (const OstMethod m : {OstMethod::Auto, OstMethod::Retrace}) {
            o.ostMethod = m;
            HitImage hits;
            traceHits(scene, cam, o, hits);
            EXPECT_EQ(hits.t, reference.t) << "method " << int(m);
            EXPECT_EQ(hits.primId, reference.primId) << "method " << int(m);
        }
    }
}

TEST(RenderView, TraceHitsAndTraceBareAgreeWithRenderView)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 4, true);
    const RayScene scene(mesh);
    const Camera cam = lookAt(CENTRE + Vec3d{3, -28, 9}, CENTRE, {0, 0, 1}, 50.0);
    const RenderOptions o = smallOptions(53, 41, true);
    HitImage fromRender, fromTrace;
    renderView(scene, cam, o, &fromRender);
    traceHits(scene, cam, o, fromTrace);
    EXPECT_EQ(fromRender.t, fromTrace.t);
    EXPECT_EQ(fromRender.primId, fromTrace.primId);
    // The bare trace has no filter, but from outside a closed surface the same rays hit.
    EXPECT_EQ(traceBare(scene, cam, 53, 41), uint64_t(hitCount(fromTrace)));
    // Rendering into a reused image gives the same pixels.
    RgbImage reused = renderView(scene, lookAt({0, 0, 50}, CENTRE, {0, 1, 0}, 30.0), o);
    renderView(scene, cam, o, reused);
    EXPECT_EQ(reused.rgb, renderView(scene, cam, o).rgb);
}

TEST(RenderView, HitPointsLieOnTheSurface)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 6, true);
    const RayScene scene(mesh);
    Camera cam = lookAt(CENTRE + Vec3d{-12, 30, 5}, CENTRE, {0, 0, 1}, 60.0);
    HitImage hits;
    traceHits(scene, cam, smallOptions(40, 30, true), hits);
    int checked = 0;
    for (int y = 0; y < hits.height; ++y)
        for (int x = 0; x < hits.width; ++x) {
            if (hits.t[std::size_t(y * hits.width + x)] < 0) {
                EXPECT_THROW(hitPointMm(cam, hits, x, y), ParameterError);
                continue;
            }
            const Vec3d p = hitPointMm(cam, hits, x, y);
            EXPECT_NEAR(distance(p, CENTRE), R, 0.005 * R) << "pixel " << x << ", " << y;
            // OST: the far side, i.e. beyond the silhouette circle of tangent points, which lies
            // R^2/d in front of the centre for an eye at distance d.
            const double silhouette = -R * R / distance(cam.position, CENTRE);
            EXPECT_GT(dot(p - CENTRE, cam.forward), silhouette - 0.05) << "pixel " << x << ", " << y;
            ++checked;
        }
    EXPECT_GT(checked, 200);
    EXPECT_EQ(countHitsWithin(cam, hits, CENTRE, R * 1.01), checked);
    EXPECT_EQ(countHitsWithin(cam, hits, CENTRE, R * 0.9), 0);
    EXPECT_THROW(hitPointMm(cam, hits, 40, 0), ParameterError);
}

/// Largest colour step between horizontally adjacent pixels that both show the surface.
int maxStep(const RgbImage& img, const HitImage& hits)
{
    int m = 0;
    for (int y = 0; y < img.height; ++y)
        for (int x = 1; x < img.width; ++x) {
            const std::size_t a = std::size_t(y * img.width + x - 1), b = a + 1;
            if (hits.t[a] < 0 || hits.t[b] < 0) continue;
            for (int c = 0; c < 3; ++c) m = std::max(m, std::abs(int(img.rgb[3 * a + std::size_t(c)]) - int(img.rgb[3 * b + std::size_t(c)])));
        }
    return m;
}

TEST(RenderView, SmoothShadingHasNoFacetEdges)
{
    // A coarse sphere (320 faces) seen from inside: flat shading jumps at every edge, smooth
    // shading varies gradually.
    const TriMesh mesh = makeIcosphere(CENTRE, R, 2, true);
    const RayScene scene(mesh);
    const Camera cam = lookAt(CENTRE + Vec3d{0, 0, 6}, CENTRE + Vec3d{0, 3, 0}, {0, 0, 1}, 70.0);
    RenderOptions o = smallOptions(96, 96, true);
    HitImage hits;
    const RgbImage smooth = renderView(scene, cam, o, &hits);
    o.smoothShading = false;
    const RgbImage flat = renderView(scene, cam, o);
    const int smoothStep = maxStep(smooth, hits), flatStep = maxStep(flat, hits);
    RecordProperty("smoothStep", smoothStep);
    RecordProperty("flatStep", flatStep);
    EXPECT_LE(smoothStep, 4);
    EXPECT_GE(flatStep, 3 * smoothStep + 6);
}

TEST(RenderView, DepthCueDarkensWithDepthFromTheNearPlane)
{
    // A wall facing the camera: brightness / (1 + depth / range), depth from the near plane. A
    // small triangle outside the view, near the camera, puts the scene's box in front of the
    // near plane, so the cue starts at the near plane.
    const TriMesh wall = test::buildMesh({{-100, -100, 0}, {100, -100, 0}, {100, 100, 0}, {-100, 100, 0},
                                          {90, 90, 35}, {91, 90, 35}, {90, 91, 35}},
                                         {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}}, false);
    const RayScene scene(wall);
    Camera cam = lookAt({0, 0, 40}, {0, 0, 0}, {0, 1, 0}, 20.0);
    RenderOptions o = smallOptions(9, 9, true);
    const RgbImage plain = renderView(scene, cam, o);
    o.depthCue = true;
    o.depthCueRangeMm = 20.0;
    cam.nearMm = 20.0;  // depth 20 beyond the near plane: half the brightness in linear
    const RgbImage cued = renderView(scene, cam, o);
    const std::size_t centre = (4 * 9 + 4) * 3;
    for (int c = 0; c < 3; ++c) {
        const double lin = std::pow(plain.rgb[centre + std::size_t(c)] / 255.0, 2.2);
        EXPECT_NEAR(cued.rgb[centre + std::size_t(c)], 255.0 * std::pow(0.5 * lin, 1 / 2.2), 1.5) << "channel " << c;
    }
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

// The render steps keep one pair image per thread: writing into an image that held a larger or
// smaller pair must give exactly the pair a fresh image gets, and an input as the output is refused.
TEST(SideBySide, IntoAReusedImageIsTheFreshPair)
{
    RgbImage left{2, 3, std::vector<uint8_t>(2 * 3 * 3, 200)};
    RgbImage right{4, 3, std::vector<uint8_t>(4 * 3 * 3, 100)};
    RgbImage small{1, 1, std::vector<uint8_t>(3, 7)};
    RgbImage reused{20, 10, std::vector<uint8_t>(20 * 10 * 3, 55)};  // larger than the pair
    sideBySide(left, right, reused, 3);
    const RgbImage fresh = sideBySide(left, right, 3);
    EXPECT_EQ(reused.width, fresh.width);
    EXPECT_EQ(reused.height, fresh.height);
    EXPECT_TRUE(reused.rgb == fresh.rgb) << "the pair written into a reused image differs from a fresh one";
    sideBySide(small, small, reused, 1);  // then smaller
    EXPECT_EQ(reused.width, 3);
    EXPECT_EQ(reused.rgb.size(), std::size_t(3 * 1 * 3));
    EXPECT_THROW(sideBySide(left, right, left), ParameterError);
}

// The render steps render a pair straight into the pair image: the same bytes as the two views
// placed side by side, for sizes that are not a multiple of the 4 x 4 tiles, OST or plain,
// supersampled or not, gaps 0 and 3, and into a reused image that held other pixels.
TEST(RenderPair, IsTheTwoViewsSideBySide)
{
    const TriMesh mesh = makeIcosphere(CENTRE, R, 4, true);
    const RayScene scene(mesh);
    const Camera left = lookAt(CENTRE + Vec3d{1, -2, 3}, CENTRE + Vec3d{R, 0, 0}, {0, 0, 1}, 80.0);
    const Camera right = lookAt(CENTRE + Vec3d{5, -25, 12}, CENTRE, {0, 0, 1}, 55.0);
    RgbImage reused{40, 40, std::vector<uint8_t>(40 * 40 * 3, 77)};
    for (const bool ost : {true, false})
        for (const int supersample : {1, 2})
            for (const int gap : {0, 3}) {
                RenderOptions options = smallOptions(37, 23, ost);
                options.supersample = supersample;
                options.depthCue = true;
                const RgbImage want =
                    sideBySide(renderView(scene, left, options), renderView(scene, right, options), gap);
                renderPair(scene, left, right, options, reused, gap);
                EXPECT_EQ(reused.width, want.width);
                EXPECT_EQ(reused.height, want.height);
                EXPECT_EQ(differingPixels(reused, want, 0), 0)
                    << "ost " << ost << ", supersample " << supersample << ", gap " << gap;
                EXPECT_TRUE(reused.rgb == want.rgb);
            }
    EXPECT_THROW(renderPair(scene, left, right, smallOptions(37, 23, true), reused, -1), ParameterError);
    EXPECT_THROW(renderPair(scene, left, right, smallOptions(0, 23, true), reused), ParameterError);
}

} // namespace
} // namespace flyover
