#include "colon/path_compare.h"

#include <gtest/gtest.h>

#include <stdexcept>

using namespace flyover;

namespace {
/// A U of two 100 mm limbs 20 mm apart, joined by a 20 mm bottom, sampled every 1 mm.
std::vector<Vec3d> uPath()
{
    std::vector<Vec3d> pts;
    for (int i = 0; i <= 100; ++i) pts.push_back({0.0, 0.0, 100.0 - i});
    for (int i = 1; i <= 20; ++i) pts.push_back({double(i), 0.0, 0.0});
    for (int i = 1; i <= 100; ++i) pts.push_back({20.0, 0.0, double(i)});
    return pts;
}
} // namespace

TEST(PathCompare, PathOnTheReferenceHasNoErrorAndNoJump)
{
    const std::vector<Vec3d> ref = uPath();
    std::vector<Vec3d> path;
    for (const Vec3d& p : ref) path.push_back(p + Vec3d{0.0, 0.5, 0.0});
    const PathComparison c = comparePathToReference(path, ref);
    ASSERT_EQ(c.errorMm.size(), path.size());
    EXPECT_NEAR(c.meanErrorMm, 0.5, 1e-9);
    EXPECT_NEAR(c.p95ErrorMm, 0.5, 1e-9);
    EXPECT_NEAR(c.worstJumpMm, 1.0, 1e-9) << "a path that follows the reference moves by its own step";
    EXPECT_EQ(c.worstBackwardsMm, 0.0);
    EXPECT_NEAR(c.referenceArcMm.back(), 220.0, 1e-9);
}

TEST(PathCompare, ShortcutAcrossTheLimbsIsOneJumpOfTheSkippedLoop)
{
    const std::vector<Vec3d> ref = uPath();
    // Down the first limb to z = 50, across to the other limb, up it.
    std::vector<Vec3d> path;
    for (int i = 0; i <= 50; ++i) path.push_back({0.0, 0.0, 100.0 - i});
    for (int i = 50; i <= 100; ++i) path.push_back({20.0, 0.0, double(i)});
    const PathComparison c = comparePathToReference(path, ref);
    // Arc 50 on the first limb -> arc 120 + 50 = 170 on the second: a jump of 120 mm.
    EXPECT_NEAR(c.worstJumpMm, 120.0, 1e-9);
    EXPECT_EQ(c.worstJumpAt, 51u);
    EXPECT_EQ(c.meanErrorMm, 0.0);
}

TEST(PathCompare, EmptyInputIsRefused)
{
    EXPECT_THROW(comparePathToReference({}, uPath()), std::invalid_argument);
    EXPECT_THROW(comparePathToReference(uPath(), {}), std::invalid_argument);
}
