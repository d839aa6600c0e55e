// bench/mask_to_ct: the CT it makes of a mask has the mask's geometry (or, padded, its lattice),
// its air below the segment stage's -800 HU is the mask and the air outside the body, and the
// tissues have the values it promises; bad input gets one line and no file.
#include "colon/phantom.h"
#include "volume/image.h"
#include "volume/image_io.h"
#include "tests/pipeline/cli_runner.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

using ToolRun = flyover::test::CliResult;

ToolRun runMaskToCt(const std::string& args) { return flyover::test::runProgram(MASK_TO_CT_BIN, args); }

class MaskToCt : public ::testing::Test {
protected:
    void SetUp() override
    {
        dir = fs::temp_directory_path() / ("mask-to-ct-test-" + std::to_string(::getpid()));
        fs::create_directories(dir);
    }
    void TearDown() override { fs::remove_all(dir); }
    std::string path(const std::string& name) const { return (dir / name).string(); }
    fs::path dir;
};

// NIfTI stores spacing and origin as float32 and the direction as a quaternion: a geometry
// read back agrees to float precision, not to the bit.
void expectSameGeometry(const ImageGeometry& a, const ImageGeometry& b, const std::string& what)
{
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(a.size[c], b.size[c]) << what << ": size along axis " << c;
        EXPECT_NEAR(a.spacingMm[c], b.spacingMm[c], 1e-5) << what << ": spacing along axis " << c;
        EXPECT_NEAR(a.originMm[c], b.originMm[c], 1e-3) << what << ": origin " << c;
        for (int r = 0; r < 3; ++r)
            EXPECT_NEAR(a.direction[r][c], b.direction[r][c], 1e-5) << what << ": direction[" << r << "][" << c << "]";
    }
}

/// Voxels below `airHu` that are not reached from the field's edge within their slice
/// (4-connected, as the ingest marks the air outside the body): the body's inner air.
std::vector<uint8_t> innerAir(const Image3<float>& ct, float airHu)
{
    const auto& g = ct.geometry;
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    std::vector<uint8_t> air(ct.voxels.size());
    for (std::size_t v = 0; v < air.size(); ++v) air[v] = ct.voxels[v] < airHu ? 1 : 0;
    std::vector<std::pair<int64_t, int64_t>> stack;
    for (int64_t k = 0; k < nz; ++k) {
        uint8_t* s = air.data() + std::size_t(nx * ny * k);
        auto push = [&](int64_t i, int64_t j) {
            if (i >= 0 && j >= 0 && i < nx && j < ny && s[i + nx * j] == 1) {
                s[i + nx * j] = 2;
                stack.emplace_back(i, j);
            }
        };
        for (int64_t i = 0; i < nx; ++i) push(i, 0), push(i, ny - 1);
        for (int64_t j = 0; j < ny; ++j) push(0, j), push(nx - 1, j);
        while (!stack.empty()) {
            const auto [i, j] = stack.back();
            stack.pop_back();
            push(i - 1, j), push(i + 1, j), push(i, j - 1), push(i, j + 1);
        }
        for (int64_t v = 0; v < nx * ny; ++v) s[v] = s[v] == 1 ? 1 : 0;
    }
    return air;
}

struct Stats {
    double sum = 0, sum2 = 0, lo = 1e300, hi = -1e300;
    int64_t n = 0;
    void add(double v) { sum += v, sum2 += v * v, lo = std::min(lo, v), hi = std::max(hi, v), ++n; }
    double mean() const { return sum / double(n); }
    double sd() const { return std::sqrt(std::max(0.0, sum2 / double(n) - mean() * mean())); }
};

} // namespace

TEST_F(MaskToCt, SmallPhantomMaskKeepsItsGeometryAndItsAirIsTheMask)
{
    PhantomParams params;  // small, seed 1: a whole colon inside the field
    const Phantom phantom = makePhantom(params);
    writeImage(phantom.truthLumen, path("mask.nii.gz"));
    const ToolRun run = runMaskToCt(path("mask.nii.gz") + " " + path("ct.nii.gz"));
    ASSERT_EQ(run.exitCode, 0) << run.err;
    EXPECT_EQ(run.err.find("warning"), std::string::npos) << "the phantom's colon does not touch the field's edge: " << run.err;

    const Image3<float> mask = readImage(path("mask.nii.gz"));
    const Image3<float> ct = readImage(path("ct.nii.gz"));
    expectSameGeometry(mask.geometry, ct.geometry, "CT against the mask");
    ASSERT_EQ(mask.voxels.size(), ct.voxels.size());

    // The CT path's air (below -800 HU) inside the body is exactly the mask.
    const std::vector<uint8_t> inner = innerAir(ct, -800.0f);
    int64_t maskOnly = 0, airOnly = 0, maskVoxels = 0;
    for (std::size_t v = 0; v < inner.size(); ++v) {
        const bool in = mask.voxels[v] != 0;
        maskVoxels += in;
        maskOnly += in && !inner[v];
        airOnly += !in && inner[v];
    }
    ASSERT_GT(maskVoxels, 1000);
    EXPECT_EQ(maskOnly, 0) << "mask voxels that are not inner air in the CT, of " << maskVoxels;
    EXPECT_EQ(airOnly, 0) << "inner air voxels of the CT outside the mask";

    // Values: lumen -1000, the wall (face neighbours of the lumen: 1 voxel <= 3 mm) 40, the
    // field's corner (outside a body 40 mm around the colon) -1000, noise 15 HU; fat and bone exist.
    const auto& g = ct.geometry;
    ASSERT_LE(std::max({g.spacingMm.x, g.spacingMm.y, g.spacingMm.z}), 3.0);
    Stats lumen, wall, corner;
    int64_t fat = 0, bone = 0;
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    for (int64_t k = 1; k + 1 < nz; ++k)
        for (int64_t j = 1; j + 1 < ny; ++j)
            for (int64_t i = 1; i + 1 < nx; ++i) {
                const std::size_t v = ct.linearIndex(i, j, k);
                const double hu = ct.voxels[v];
                fat += hu > -160 && hu < -40;
                bone += hu > 500;
                if (mask.voxels[v] != 0) {
                    lumen.add(hu);
                    continue;
                }
                const std::size_t near[6] = {v - 1, v + 1, v - std::size_t(nx), v + std::size_t(nx),
                                             v - std::size_t(nx * ny), v + std::size_t(nx * ny)};
                for (std::size_t w : near)
                    if (mask.voxels[w] != 0) {
                        wall.add(hu);
                        break;
                    }
                if (i < 4 && j < 4) corner.add(hu);
            }
    EXPECT_NEAR(lumen.mean(), -1000.0, 1.0) << lumen.n << " lumen voxels";
    EXPECT_NEAR(lumen.sd(), 15.0, 1.0);
    EXPECT_LT(lumen.hi, -900.0);
    EXPECT_NEAR(wall.mean(), 40.0, 1.0) << wall.n << " wall voxels";
    EXPECT_GT(wall.lo, -40.0);
    EXPECT_NEAR(corner.mean(), -1000.0, 2.0) << corner.n << " voxels in the field's corners along k";
    EXPECT_GT(fat, 1000) << "pericolic and subcutaneous fat voxels (-160..-40 HU)";
    EXPECT_GT(bone, 1000) << "spine voxels (> 500 HU)";

    // Without the spine no voxel is bone; the seed changes the noise only.
    const ToolRun noSpine = runMaskToCt(path("mask.nii.gz") + " " + path("ct2.nii.gz") + " --no-spine --seed 7");
    ASSERT_EQ(noSpine.exitCode, 0) << noSpine.err;
    const Image3<float> ct2 = readImage(path("ct2.nii.gz"));
    int64_t bone2 = 0, differ = 0;
    for (std::size_t v = 0; v < ct2.voxels.size(); ++v) {
        bone2 += ct2.voxels[v] > 500;
        differ += ct2.voxels[v] != ct.voxels[v];
    }
    EXPECT_EQ(bone2, 0);
    EXPECT_GT(differ, int64_t(ct2.voxels.size() / 2)) << "another seed, other noise";
}

TEST_F(MaskToCt, LabelMapOnAnObliqueAnisotropicGridPaddedOnTheSameLattice)
{
    // A label map: a tube of label 3 along k from edge to edge, a block of label 1 beside it.
    Image3<uint8_t> labels;
    auto& g = labels.geometry;
    g.size = {40, 36, 30};
    g.spacingMm = {0.8, 0.9, 1.25};
    g.originMm = {-10.5, 20.25, 100.0};
    const double c = std::cos(0.5), s = std::sin(0.5);
    g.direction = {{{c, -s, 0}, {s, c, 0}, {0, 0, 1}}};
    labels.voxels.assign(std::size_t(g.voxelCount()), 0);
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                const double x = (double(i) - 12) * g.spacingMm.x, y = (double(j) - 18) * g.spacingMm.y;
                if (x * x + y * y < 36.0) labels.at(i, j, k) = 3;
                else if (i >= 26 && i < 34 && j >= 10 && j < 26 && k >= 5 && k < 25) labels.at(i, j, k) = 1;
            }
    writeImage(labels, path("labels.nii.gz"));
    const Image3<float> mask = readImage(path("labels.nii.gz"));

    // Unpadded: the tube reaches two faces of the field, and the tool says so.
    const ToolRun plain = runMaskToCt(path("labels.nii.gz") + " " + path("plain.nii.gz") + " --label 3");
    ASSERT_EQ(plain.exitCode, 0) << plain.err;
    EXPECT_NE(plain.err.find("touches 2 of the field's 6 faces"), std::string::npos) << plain.err;
    expectSameGeometry(mask.geometry, readImage(path("plain.nii.gz")).geometry, "unpadded CT against the mask");

    const ToolRun padded = runMaskToCt(path("labels.nii.gz") + " " + path("ct.nii.gz") + " --label 3 --pad-mm 5 --mask-out " +
                                   path("padded.nii.gz"));
    ASSERT_EQ(padded.exitCode, 0) << padded.err;
    EXPECT_EQ(padded.err, "");
    const Image3<float> ct = readImage(path("ct.nii.gz"));
    const Image3<float> paddedMask = readImage(path("padded.nii.gz"));
    const std::array<int64_t, 3> pad{7, 6, 4};  // ceil(5 / spacing)
    ImageGeometry want = mask.geometry;
    for (int a = 0; a < 3; ++a) want.size[a] += 2 * pad[a];
    want.originMm = mask.geometry.worldFromIndex({-7.0, -6.0, -4.0});
    expectSameGeometry(want, ct.geometry, "padded CT");
    expectSameGeometry(want, paddedMask.geometry, "padded mask");

    int64_t tube = 0, labelOne = 0;
    for (int64_t k = 0; k < g.size[2]; ++k)
        for (int64_t j = 0; j < g.size[1]; ++j)
            for (int64_t i = 0; i < g.size[0]; ++i) {
                const float label = mask.at(i, j, k);
                const float hu = ct.at(i + pad[0], j + pad[1], k + pad[2]);
                const float inPadded = paddedMask.at(i + pad[0], j + pad[1], k + pad[2]);
                EXPECT_EQ(inPadded, label == 3 ? 1.0f : 0.0f) << "padded mask at " << i << "," << j << "," << k;
                if (label == 3) {
                    ++tube;
                    EXPECT_LT(hu, -800.0f) << "tube voxel " << i << "," << j << "," << k;
                } else if (label == 1) {
                    ++labelOne;
                    EXPECT_GT(hu, -800.0f) << "label 1 is not lumen: " << i << "," << j << "," << k;
                }
            }
    EXPECT_GT(tube, 1000);
    EXPECT_GT(labelOne, 1000);
    // The padding around the tube's ends is its wall, not air: the tube no longer reaches the edge.
    EXPECT_GT(ct.at(12 + pad[0], 18 + pad[1], 0), -800.0f);
    EXPECT_GT(ct.at(12 + pad[0], 18 + pad[1], ct.geometry.size[2] - 1), -800.0f);
}

TEST_F(MaskToCt, BadInputGetsOneLineAndNoFile)
{
    Image3<uint8_t> empty;
    empty.geometry.size = {8, 8, 8};
    empty.voxels.assign(512, 0);
    writeImage(empty, path("empty.nii.gz"));
    Image3<uint8_t> labels = empty;
    labels.voxels[100] = 1;
    labels.voxels[200] = 3;
    writeImage(labels, path("labels.nii.gz"));

    struct Case {
        std::string args, expect;
    };
    const std::vector<Case> cases = {
        {path("missing.nii.gz") + " " + path("out.nii.gz"), path("missing.nii.gz")},
        {path("empty.nii.gz") + " " + path("out.nii.gz"), "empty mask"},
        {path("labels.nii.gz") + " " + path("out.nii.gz") + " --label 7", "label 7 is absent (values present: 0 1 3)"},
        {path("labels.nii.gz") + " " + path("out.nii.gz") + " --label 2.5", "--label"},
        {path("labels.nii.gz") + " " + path("out.nii.gz") + " --noise-hu -3", "--noise-hu"},
        {path("labels.nii.gz") + " " + path("out.png"), "expected a .nii.gz or .nii file name"},
        {path("labels.nii.gz") + " " + path("out.nii.gz") + " --pad", "--pad: expected a value"},
    };
    for (const Case& c : cases) {
        const ToolRun r = runMaskToCt(c.args);
        EXPECT_EQ(r.exitCode, 1) << c.args << "\n" << r.err;
        EXPECT_EQ(flyover::test::lineCount(r.err), 1) << c.args << "\n" << r.err;
        EXPECT_NE(r.err.find(c.expect), std::string::npos) << "expected \"" << c.expect << "\" in: " << r.err;
        EXPECT_FALSE(fs::exists(path("out.nii.gz")) || fs::exists(path("out.png"))) << c.args;
        fs::remove(path("out.nii.gz"));
        fs::remove(path("out.png"));
    }
}
