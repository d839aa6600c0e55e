#include "render/overview.h"

#include "test_meshes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <string>

namespace flyover {
namespace {

TEST(CanonicalViews, SixDistinctAxisViewsWithPerpendicularUp)
{
    std::set<std::string> names;
    for (const CanonicalView& v : canonicalViews()) {
        names.insert(v.name);
        EXPECT_NEAR(length(v.viewDir), 1.0, 1e-12) << v.name;
        EXPECT_NEAR(length(v.up), 1.0, 1e-12) << v.name;
        EXPECT_NEAR(dot(v.viewDir, v.up), 0.0, 1e-12) << v.name;
    }
    EXPECT_EQ(names, (std::set<std::string>{"anterior", "posterior", "left", "right", "superior", "inferior"}));
    // Anterior view, radiological convention: the patient's right (-x in LPS) on the image's left.
    const CanonicalView& a = canonicalViews()[0];
    EXPECT_EQ(std::string(a.name), "anterior");
    const Camera c = overviewCamera({-10, -10, -10}, {10, 10, 10}, a.viewDir, a.up, 30.0);
    EXPECT_LT(dot(Vec3d{-1, 0, 0}, c.right), 0.0);
    EXPECT_GT(dot(c.up, Vec3d{0, 0, 1}), 0.99);
}

TEST(OverviewCamera, FramesTheBoxTightly)
{
    // Axis-aligned view of a cube: the nearest face's edges reach the 4% margin exactly.
    const Camera c = overviewCamera({0, 0, 0}, {100, 100, 100}, {0, 1, 0}, {0, 0, 1}, 30.0);
    const double tanHalf = std::tan(15.0 * PI / 180.0);
    const Vec3d nearCorner{100, 0, 100};
    const Vec3d d = nearCorner - c.position;
    EXPECT_NEAR(dot(d, c.right) / (dot(d, c.forward) * tanHalf), 0.96, 1e-9);
}

TEST(DrawMarker, RingAndDotAtTheProjectedPoint)
{
    const Camera c = lookAt({0, 0, 100}, {0, 0, 0}, {0, 1, 0}, 40.0);
    RgbImage img{101, 101, std::vector<uint8_t>(101 * 101 * 3, 0)};
    // 10 mm at depth 100 with tan(20 deg): 10 / (100 * 0.364) * 50.5 = 13.9 px.
    drawMarker(img, c, OverviewMarker{{0, 0, 0}, 10.0});
    auto at = [&](int x, int y) { return img.rgb[std::size_t(y * 101 + x) * 3 + 1]; };
    EXPECT_GT(at(50, 50), 200);      // the dot
    EXPECT_EQ(at(50, 50 - 8), 0);    // between dot and ring
    EXPECT_GT(at(50 + 14, 50), 100); // on the ring
    EXPECT_EQ(at(5, 5), 0);          // far away
    // A point behind the camera draws nothing; off-image parts are clipped.
    RgbImage untouched{101, 101, std::vector<uint8_t>(101 * 101 * 3, 0)};
    drawMarker(untouched, c, OverviewMarker{{0, 0, 200}, 10.0});
    EXPECT_EQ(untouched.rgb, std::vector<uint8_t>(101 * 101 * 3, 0));
    drawMarker(untouched, c, OverviewMarker{{36, 0, 0}, 10.0});
    RgbImage bad{3, 3, {}};
    EXPECT_THROW(drawMarker(bad, c, OverviewMarker{}), ParameterError);
}

} // namespace
} // namespace flyover
