// Masks that hold no plausible colon, through the command line: an empty file, a mask of
// zeros, a label that is absent, small pieces only, a single ball. Each: exit 1, one line on
// stderr naming the file and the problem, and nothing of the segment stage in the study.
#include "tests/pipeline/cli_runner.h"
#include "volume/image_io.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace flyover::test {
namespace {

class BadMaskCli : public ::testing::Test {
protected:
    void SetUp() override
    {
        mRoot = fs::temp_directory_path() / ("flyover-badmask-" + std::to_string(::getpid()));
        fs::remove_all(mRoot);
        fs::create_directories(mRoot);
    }
    void TearDown() override { fs::remove_all(mRoot); }

    /// A 100^3 mask at 1 mm, label 1 inside the given balls (centre, radius in mm).
    std::string writeBalls(const std::string& name, const std::vector<std::pair<Vec3d, double>>& balls) const
    {
        Image3<uint8_t> img;
        img.geometry.size = {100, 100, 100};
        img.geometry.originMm = {-50, 20, -700};
        img.voxels.assign(std::size_t(img.geometry.voxelCount()), 0);
        for (int64_t k = 0; k < 100; ++k)
            for (int64_t j = 0; j < 100; ++j)
                for (int64_t i = 0; i < 100; ++i)
                    for (const auto& [c, r] : balls)
                        if (distance(Vec3d{double(i), double(j), double(k)}, c) < r) img.at(i, j, k) = 1;
        const std::string path = (mRoot / name).string();
        writeImage(img, path);
        return path;
    }

    /// Runs the segment stage on `mask`; checks exit 1, one line naming the file and holding
    /// `problem`, and that the study holds no lumen and no segment entry.
    void expectRefused(const std::string& mask, const std::string& problem, const std::string& extra = "")
    {
        const std::string study = (mRoot / ("study-" + fs::path(mask).filename().string())).string();
        const CliResult r = runFlyover("--quiet run --mask " + mask + extra + " --study " + study + " --until segment");
        SCOPED_TRACE(mask + ": stderr: " + r.err);
        EXPECT_EQ(r.exitCode, 1);
        EXPECT_EQ(lineCount(r.err), 1);
        EXPECT_NE(r.err.find(fs::path(mask).filename().string()), std::string::npos);
        EXPECT_NE(r.err.find(problem), std::string::npos);
        EXPECT_FALSE(fs::exists(fs::path(study) / "lumen.vdb"));
        const fs::path manifest = fs::path(study) / "manifest.json";
        if (fs::exists(manifest)) {
            std::ifstream in(manifest);
            const nlohmann::json m = nlohmann::json::parse(in);
            for (const auto& s : m.at("stages")) EXPECT_NE(s.value("stage", ""), "segment") << m.dump();
        }
    }

    fs::path mRoot;
};

TEST_F(BadMaskCli, EachBadMaskOneLineExitOneNothingWritten)
{
    const std::string empty = (mRoot / "empty.nii.gz").string();
    std::ofstream(empty).close();
    expectRefused(empty, "empty");
    // The empty file is refused before the study folder is made.
    EXPECT_FALSE(fs::exists(mRoot / "study-empty.nii.gz"));

    expectRefused(writeBalls("zeros.nii.gz", {}), "no voxel holds a non-zero label");
    const std::string ball = writeBalls("ball.nii.gz", {{{50, 50, 50}, 25}});
    expectRefused(ball, "no plausible colon");
    expectRefused(ball, "no voxel holds label 7", " --label 7");
    expectRefused(writeBalls("pieces.nii.gz", {{{25, 25, 25}, 8}, {{70, 70, 50}, 8}, {{30, 70, 80}, 8}}),
                  "no plausible colon");
}

// A colon whose both ends lie high (a U: the lowest lumen lies halfway along it, 80 mm below
// either end, and no end lies near it): the path cannot start in a rectum it does not see. The
// run finishes, says so in a warning line naming the distance, and `flyover status` shows the
// study as needing review; never a silent success.
TEST_F(BadMaskCli, ARectumAboveTheLowestLumenIsAWarningAndAStudyToReview)
{
    Image3<uint8_t> img;
    img.geometry.size = {100, 40, 100};
    img.geometry.originMm = {-50, 20, -700};
    img.voxels.assign(std::size_t(img.geometry.voxelCount()), 0);
    // Two limbs at x = 25 and x = 75 from z = 90 down to z = 35, joined by a half circle below (lowest at z = 3).
    auto axisDistance = [](double x, double z) {
        if (z >= 35) return std::min(std::fabs(x - 25), std::fabs(x - 75));
        return std::fabs(std::hypot(x - 50, z - 35) - 25.0);
    };
    for (int64_t k = 0; k < 100; ++k)
        for (int64_t j = 0; j < 40; ++j)
            for (int64_t i = 0; i < 100; ++i) {
                const double x = double(i), y = double(j) - 20, z = double(k);
                if (z > 90 || z < -10) continue;
                const double d = std::hypot(axisDistance(x, z), y);
                if (d < 7.0 && k > 0) img.at(i, j, k) = 1;
            }
    const std::string mask = (mRoot / "u.nii.gz").string();
    writeImage(img, mask);
    const std::string study = (mRoot / "study-u").string();
    const CliResult r = runFlyover("run --mask " + mask + " --study " + study + " --until centerline");
    SCOPED_TRACE("stdout: " + r.out + "\nstderr: " + r.err);
    EXPECT_EQ(r.exitCode, 0);
    const std::string all = r.out + r.err;
    EXPECT_NE(all.find("mm above the lowest lumen point"), std::string::npos) << "no warning line";
    EXPECT_NE(all.find("needs review"), std::string::npos) << "the run does not say the study needs review";
    const CliResult st = runFlyover("status --study " + study);
    EXPECT_NE(st.out.find("needs review: centerline: the path starts"), std::string::npos) << "status: " << st.out;
}

} // namespace
} // namespace flyover::test
