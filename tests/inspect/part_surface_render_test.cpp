// The surfaces and renders of a part (flyover inspect) from a known analysis: orientation for
// OST, one closed surface per void, every void visible in an OST overview and hidden in the
// normal render, counted from the primitive IDs of the hit triangles.
#include "tests/inspect/part_fixture.h"

#include "render/overview.h"
#include "inspect/part_render.h"
#include "render/ray_scene.h"
#include "inspect/part_surface.h"

#include <gtest/gtest.h>

#include <map>

namespace flyover {
namespace {

struct PartSurfaceRenderTest : ::testing::Test {
    static void SetUpTestSuite()
    {
        openvdb::initialize();
        part = new test::TestPart(test::makeTestPart(96));
        grid = test::partGrid(*part);
        analysis = new PartAnalysis(test::truthAnalysis(*part, *grid));
        surface = new PartSurface(makePartSurface(*grid, *analysis, PartSurfaceParams{}));
    }
    static void TearDownTestSuite()
    {
        delete surface;
        delete analysis;
        delete part;
        grid.reset();
    }
    static test::TestPart* part;
    static openvdb::FloatGrid::Ptr grid;
    static PartAnalysis* analysis;
    static PartSurface* surface;
};
test::TestPart* PartSurfaceRenderTest::part = nullptr;
openvdb::FloatGrid::Ptr PartSurfaceRenderTest::grid;
PartAnalysis* PartSurfaceRenderTest::analysis = nullptr;
PartSurface* PartSurfaceRenderTest::surface = nullptr;

TEST_F(PartSurfaceRenderTest, OneClosedSurfacePerVoidNormalsIntoTheMaterial)
{
    const TriMesh& mesh = surface->mesh;
    ASSERT_EQ(surface->voids.size(), part->voids.size());
    EXPECT_GT(surface->outer.count, 1000);
    EXPECT_EQ(surface->outer.first, 0);
    EXPECT_EQ(surface->unassignedFaces, 0);
    EXPECT_TRUE(surface->report.isSound()) << "outward " << surface->report.orientation.outward << ", degenerate "
                                           << surface->report.check.degenerateFaces;
    for (std::size_t k = 0; k < part->voids.size(); ++k) {
        const FaceRange& r = surface->voids[k];
        ASSERT_GT(r.count, 20) << "void " << k + 1 << " has no surface of its own";
        // Its faces surround the void's centre, and each points away from it: into the material.
        const Vec3d centre = part->centreMm(part->voids[k]);
        Vec3d mean{0, 0, 0};
        int64_t outwardFromVoid = 0;
        for (int64_t f = r.first; f < r.first + r.count; ++f) {
            const auto fh = mesh.face_handle(int(f));
            std::array<Vec3d, 3> p;
            int i = 0;
            for (const auto v : mesh.fv_range(fh)) {
                const auto q = mesh.point(v);
                p[std::size_t(i++)] = Vec3d{q[0], q[1], q[2]};
            }
            const Vec3d c = (p[0] + p[1] + p[2]) / 3.0;
            mean += c;
            outwardFromVoid += dot(cross(p[1] - p[0], p[2] - p[0]), c - centre) > 0;
        }
        mean = mean / double(r.count);
        EXPECT_LT(distance(mean, centre), part->voxelMm()) << "void " << k + 1;
        EXPECT_EQ(outwardFromVoid, r.count) << "void " << k + 1 << ": faces whose normal points into the void";
        for (int64_t f = r.first; f < r.first + r.count; f += 7) EXPECT_EQ(surface->voidOfFace(f), int(k) + 1);
    }
    EXPECT_EQ(surface->voidOfFace(0), 0);
    // The outer surface's normals point into the material: outwards from the bore's axis on
    // the bore, inwards on the mantle. Count the mantle faces at mid height.
    const double c = 0.5 * (part->geometry.size[0] - 1);
    const Vec3d axis = part->geometry.worldFromIndex(Vec3d{c, c, 0});
    int64_t mantle = 0, inward = 0;
    for (int64_t f = 0; f < surface->outer.count; ++f) {
        const auto fh = mesh.face_handle(int(f));
        std::array<Vec3d, 3> p;
        int i = 0;
        for (const auto v : mesh.fv_range(fh)) {
            const auto q = mesh.point(v);
            p[std::size_t(i++)] = Vec3d{q[0], q[1], q[2]};
        }
        const Vec3d ce = (p[0] + p[1] + p[2]) / 3.0;
        const Vec3d radial{ce.x - axis.x, ce.y - axis.y, 0};
        if (length(radial) < (part->radius - 2) * part->voxelMm()) continue;
        if (std::abs(ce.z - part->geometry.worldFromIndex(Vec3d{0, 0, 48}).z) > 10) continue;
        ++mantle;
        inward += dot(cross(p[1] - p[0], p[2] - p[0]), radial) < 0;
    }
    ASSERT_GT(mantle, 100);
    EXPECT_EQ(inward, mantle);
    // The outer surface is the cylinder, not the scan's box: its extent across is the diameter.
    double lo = 1e9, hi = -1e9;
    for (int64_t f = 0; f < surface->outer.count; ++f)
        for (const auto v : mesh.fv_range(mesh.face_handle(int(f)))) {
            lo = std::min(lo, double(mesh.point(v)[0]));
            hi = std::max(hi, double(mesh.point(v)[0]));
        }
    EXPECT_NEAR(hi - lo, 2 * part->radius * part->voxelMm(), 1.5 * part->voxelMm());
}

TEST_F(PartSurfaceRenderTest, EveryVoidShowsInAnOstOverviewAndNoneInTheNormalRender)
{
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    const TriMesh& mesh = surface->mesh;
    for (const auto v : mesh.vertices())
        for (int d = 0; d < 3; ++d) xyz.push_back(mesh.point(v)[d]);
    for (const auto f : mesh.faces())
        for (const auto v : mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
    const RayScene scene(std::move(xyz), std::move(tris));
    std::vector<Rgb8> colours(scene.triangleCount(), PART_GREY);
    RenderOptions ro;
    ro.widthPx = ro.heightPx = 160;
    std::map<int, int64_t> bestOst, totalNormal;
    int64_t outerInNormal = 0;
    for (const CanonicalView& view : canonicalViews()) {
        const Camera cam = overviewCamera(scene.boundsMin(), scene.boundsMax(), view.viewDir, view.up, 30.0);
        for (const bool ost : {true, false}) {
            ro.ost = ost;
            HitImage hits;
            renderFaceColours(scene, cam, ro, colours, &hits);
            std::map<int, int64_t> px;
            for (const uint32_t prim : hits.primId)
                if (prim != UINT32_MAX) ++px[surface->voidOfFace(int64_t(prim))];
            for (std::size_t k = 1; k <= part->voids.size(); ++k) {
                if (ost) bestOst[int(k)] = std::max(bestOst[int(k)], px[int(k)]);
                else totalNormal[int(k)] += px[int(k)];
            }
            if (!ost) outerInNormal += px[0];
        }
    }
    EXPECT_GT(outerInNormal, 6 * 1000) << "the normal render should show the part's outside";
    for (std::size_t k = 1; k <= part->voids.size(); ++k) {
        EXPECT_GT(bestOst[int(k)], 3) << "void " << k << " shows in no OST overview";
        EXPECT_EQ(totalNormal[int(k)], 0) << "void " << k << " shows through the opaque part in the normal render";
    }
}

TEST_F(PartSurfaceRenderTest, SampleHitsHoldEveryRayTheCentreOnesAmongThem)
{
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    const TriMesh& mesh = surface->mesh;
    for (const auto v : mesh.vertices())
        for (int d = 0; d < 3; ++d) xyz.push_back(mesh.point(v)[d]);
    for (const auto f : mesh.faces())
        for (const auto v : mesh.fv_range(f)) tris.push_back(uint32_t(v.idx()));
    const RayScene scene(std::move(xyz), std::move(tris));
    const std::vector<Rgb8> colours(scene.triangleCount(), PART_GREY);
    const CanonicalView& view = canonicalViews().front();
    const Camera cam = overviewCamera(scene.boundsMin(), scene.boundsMax(), view.viewDir, view.up, 30.0);
    for (const int n : {1, 2, 3}) {
        RenderOptions ro;
        ro.widthPx = ro.heightPx = 40;  // coarse: voids a pixel or two across
        ro.supersample = n;
        ro.ost = true;
        HitImage hits;
        std::vector<uint32_t> rays;
        renderFaceColours(scene, cam, ro, colours, &hits, &rays);
        ASSERT_EQ(rays.size(), std::size_t(40 * 40 * n * n));
        const std::size_t centre = n == 1 ? 0 : std::size_t((n / 2) * n + n / 2);
        int64_t voidPixels = 0, voidRays = 0;
        for (std::size_t p = 0; p < hits.primId.size(); ++p) {
            ASSERT_EQ(rays[p * std::size_t(n * n) + centre], hits.primId[p]) << "pixel " << p << ", supersample " << n;
            if (hits.primId[p] != UINT32_MAX && surface->voidOfFace(int64_t(hits.primId[p])) > 0) ++voidPixels;
        }
        for (const uint32_t prim : rays) {
            ASSERT_TRUE(prim == UINT32_MAX || prim < scene.triangleCount());
            if (prim != UINT32_MAX && surface->voidOfFace(int64_t(prim)) > 0) ++voidRays;
        }
        EXPECT_GT(voidRays, 0) << "supersample " << n;
        EXPECT_GE(voidRays, voidPixels) << "supersample " << n;
    }
}

TEST(PartRender, SizeColoursAndLegend)
{
    const SizeColourScale scale{0.5, 8.0};
    EXPECT_EQ(scale.position(0.5), 0.0);
    EXPECT_EQ(scale.position(8.0), 1.0);
    EXPECT_NEAR(scale.position(2.0), 0.5, 1e-12);  // logarithmic: 2 mm is halfway from 0.5 to 8
    EXPECT_NE(scale.colour(0.5), scale.colour(8.0));
    const Rgb8 small = scale.colour(0.5), large = scale.colour(8.0);
    EXPECT_GT(small[2], small[0]) << "small voids are blue";
    EXPECT_GT(large[0], large[2]) << "large voids are red";
    const RgbImage legend = sizeLegendPanel(scale, 96, 256);
    ASSERT_EQ(legend.width, 96);
    ASSERT_EQ(legend.height, 256);
    // The bar's top is the largest size's colour, its bottom the smallest's.
    auto at = [&](int x, int y) {
        const uint8_t* p = legend.rgb.data() + (std::size_t(y) * 96 + std::size_t(x)) * 3;
        return Rgb8{p[0], p[1], p[2]};
    };
    EXPECT_EQ(at(12, 48), large);
    EXPECT_EQ(at(12, 256 - 16), small);
    // Text was drawn (light pixels right of the bar).
    int light = 0;
    for (int y = 40; y < 256; ++y)
        for (int x = 30; x < 96; ++x) light += at(x, y)[0] > 200 && at(x, y)[1] > 200;
    EXPECT_GT(light, 40);
}

} // namespace
} // namespace flyover
