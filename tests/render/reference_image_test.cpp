// Image regression tests: small renders of analytic scenes compared with PNG fixtures in
// tests/render/reference/ under a bounded count of differing pixels (Embree's
// --compare-threshold idea: a channel may differ by a few levels, a few pixels may differ more,
// e.g. where a ray grazes an edge and another ISA's kernels pick the neighbouring triangle).
//
// Regenerate after an intended change of the images (and look at them):
//   FLYOVER_UPDATE_REFERENCE=1 ./render_tests --gtest_filter='ReferenceImage.*'
#include "pipeline/artifact_io.h"
#include "render/overview.h"
#include "render/render_view.h"

#include "test_meshes.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace fs = std::filesystem;

namespace flyover {
namespace {

constexpr int CHANNEL_TOLERANCE = 10;       ///< levels per channel that do not count as different
constexpr double PIXEL_BUDGET = 0.01;       ///< fraction of pixels allowed to differ more

fs::path referencePath(const std::string& name)
{
    return fs::path(FLYOVER_SOURCE_DIR) / "tests" / "render" / "reference" / name;
}

void compareWithReference(const RgbImage& image, const std::string& name)
{
    const fs::path path = referencePath(name);
    if (const char* update = std::getenv("FLYOVER_UPDATE_REFERENCE"); update && std::string(update) == "1") {
        fs::create_directories(path.parent_path());
        writePng(path.string(), image);
        GTEST_SKIP() << "wrote " << path;
    }
    ASSERT_TRUE(fs::exists(path)) << path << " missing: run with FLYOVER_UPDATE_REFERENCE=1 to create it";
    const RgbImage reference = readPng(path.string());
    ASSERT_EQ(reference.width, image.width) << name;
    ASSERT_EQ(reference.height, image.height) << name;
    int differing = 0, maxDiff = 0;
    for (std::size_t p = 0; p < image.rgb.size(); p += 3) {
        int d = 0;
        for (std::size_t c = 0; c < 3; ++c) d = std::max(d, std::abs(int(image.rgb[p + c]) - int(reference.rgb[p + c])));
        maxDiff = std::max(maxDiff, d);
        differing += d > CHANNEL_TOLERANCE ? 1 : 0;
    }
    ::testing::Test::RecordProperty(name + " differing", differing);
    const int budget = int(PIXEL_BUDGET * image.width * image.height);
    EXPECT_LE(differing, budget) << name << ": " << differing << " pixels differ by more than " << CHANNEL_TOLERANCE
                                 << " levels (largest difference " << maxDiff << ")";
}

const Vec3d TORUS_CENTRE{3, -2, 5};

TriMesh torus() { return test::makeTorus(TORUS_CENTRE, 20.0, 6.0, 96, 32, /*inward=*/true); }

Camera torusCamera() { return lookAt(TORUS_CENTRE + Vec3d{10, -55, 35}, TORUS_CENTRE, {0, 0, 1}, 50.0); }

TEST(ReferenceImage, OstTorusFromOutside)
{
    const TriMesh mesh = torus();
    const RayScene scene(mesh);
    RenderOptions o;
    o.widthPx = o.heightPx = 80;
    o.depthCue = true;
    compareWithReference(renderView(scene, torusCamera(), o), "ost_torus.png");
}

TEST(ReferenceImage, PlainTorusFromOutside)
{
    const TriMesh mesh = torus();
    const RayScene scene(mesh);
    RenderOptions o;
    o.widthPx = o.heightPx = 80;
    o.ost = false;
    o.depthCue = true;
    compareWithReference(renderView(scene, torusCamera(), o), "plain_torus.png");
}

TEST(ReferenceImage, FlyoverPairBesideAFold)
{
    const test::FoldedTube tube;
    const TriMesh mesh = tube.mesh(0.5, 96);
    const RayScene scene(mesh);
    const Centerline line = tube.centerline();
    const CenterlinePoint& p = line.points[std::size_t(tube.zFold - 6.0 - line.points.front().positionMm.z)];
    RenderOptions o;
    o.widthPx = o.heightPx = 64;
    o.depthCue = true;
    o.depthCueRangeMm = 40.0;
    const auto cams = flyoverCameras(p, FlyoverParams{});
    compareWithReference(sideBySide(renderView(scene, cams[0], o), renderView(scene, cams[1], o)),
                         "flyover_pair_fold.png");
}

TEST(ReferenceImage, FlythroughTowardsAFold)
{
    const test::FoldedTube tube;
    const TriMesh mesh = tube.mesh(0.5, 96);
    const RayScene scene(mesh);
    const Centerline line = tube.centerline();
    RenderOptions o;
    o.widthPx = o.heightPx = 64;
    o.depthCue = true;
    o.depthCueRangeMm = 40.0;
    const Camera cam = flythroughCamera(line.points[25], true, 90.0);
    compareWithReference(renderView(scene, cam, o), "flythrough_fold.png");
}

TEST(ReferenceImage, OverviewWithMarker)
{
    const TriMesh mesh = torus();
    const RayScene scene(mesh);
    RenderOptions o;
    o.widthPx = o.heightPx = 80;
    o.supersample = 2;
    o.depthCue = true;
    const CanonicalView& anterior = canonicalViews()[0];
    const Camera cam = overviewCamera(scene.boundsMin(), scene.boundsMax(), anterior.viewDir, anterior.up, 30.0);
    RgbImage image = renderView(scene, cam, o);
    drawMarker(image, cam, OverviewMarker{TORUS_CENTRE + Vec3d{20, 0, 0}, 6.0});
    compareWithReference(image, "overview_marker.png");
}

} // namespace
} // namespace flyover
