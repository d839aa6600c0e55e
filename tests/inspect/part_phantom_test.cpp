// The industrial part phantom (inspect/part_phantom.h) and the void analysis (inspect/voids.h)
// against its truth: every void found, volumes, kinds, porosity.
#include "inspect/part_phantom.h"
#include "volume/vec3.h"
#include "pipeline/artifact_io.h"
#include "inspect/part_phantom_io.h"
#include "volume/error.h"
#include "volume/image_io.h"
#include "volume/progress.h"
#include "inspect/voids.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <filesystem>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

struct Generated {
    PartTruth truth;
    std::vector<uint16_t> voxels;  // whole volume (small sizes only)
};

Generated generate(const PartPhantomParams& p)
{
    Generated g;
    const std::size_t area = static_cast<std::size_t>(p.size) * p.size;
    g.voxels.resize(area * p.size);
    int64_t expected = 0;
    g.truth = generatePartPhantom(p, [&](int64_t k, const std::vector<uint16_t>& slice) {
        EXPECT_EQ(k, expected++) << "slices in order";
        std::copy(slice.begin(), slice.end(), g.voxels.begin() + static_cast<std::ptrdiff_t>(k * area));
    });
    EXPECT_EQ(expected, p.size);
    return g;
}

/// The CT as inspect hands it over: a FloatGrid of the grey values, LPS transform. With
/// `sparse`, voxels farther than 5 voxels from the part's outer cylinders stay inactive
/// background (the air grey value), as an ingest with a grey-value background stores them.
openvdb::FloatGrid::Ptr toGrid(const Generated& g, bool sparse = false)
{
    const PartPhantomParams& p = g.truth.params;
    const int n = p.size;
    auto grid = openvdb::FloatGrid::create(static_cast<float>(p.airGrey));
    auto xf = openvdb::math::Transform::createLinearTransform(p.voxelMm);
    xf->postTranslate(openvdb::Vec3d(g.truth.geometry.originMm.x, g.truth.geometry.originMm.y, g.truth.geometry.originMm.z));
    grid->setTransform(xf);
    auto acc = grid->getAccessor();
    const double c = 0.5 * (n - 1), margin = 5;
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                const bool border = i == 0 || j == 0 || k == 0 || i == n - 1 || j == n - 1 || k == n - 1;
                const double r = std::hypot(i - c, j - c);
                const bool nearBody = r <= 0.34 * n + margin && k >= 0.10 * n - margin && k <= 0.90 * n + margin;
                const bool nearFlange = r <= 0.46 * n + margin && k >= 0.10 * n - margin && k <= 0.22 * n + margin;
                if (sparse && !border && !nearBody && !nearFlange) continue;
                acc.setValueOn(openvdb::Coord(i, j, k), g.voxels[(static_cast<std::size_t>(k) * n + j) * n + i]);
            }
    return grid;
}

std::string describe(const PartVoidTruth& t)
{
    std::ostringstream o;
    o << "truth void " << t.id << " (" << t.kind << ", " << t.voxels << " voxels, centroid " << t.centroidLps.x << ","
      << t.centroidLps.y << "," << t.centroidLps.z << ")";
    return o.str();
}

/// Every truth expectation of the void analysis on one phantom.
void expectAnalysisMatchesTruth(const Generated& g, const PartAnalysis& a)
{
    const PartTruth& t = g.truth;
    const double vox = t.params.voxelMm, vox3 = vox * vox * vox;
    int internal = 0;
    for (const PartVoidTruth& tv : t.voids) {
        const VoidInfo* hit = nullptr;
        for (const VoidInfo& v : a.voids)
            if (distance(v.centroidLps, tv.centroidLps) <= 1.0 * vox) hit = &v;
        if (!tv.internal) {
            // the open crack belongs to the outside air: nothing listed anywhere near it
            for (const VoidInfo& v : a.voids)
                EXPECT_GT(distance(v.centroidLps, tv.centroidLps), 12 * vox)
                    << describe(tv) << " is open to the surface but void " << v.id << " was listed near it";
            continue;
        }
        ++internal;
        ASSERT_NE(hit, nullptr) << describe(tv) << ": no listed void with its centroid within 1 voxel";
        const double eqdVoxels = tv.equivalentDiameterMm / vox;
        if (eqdVoxels >= 4.0) {
            EXPECT_NEAR(hit->volumeMm3, tv.volumeMm3, 0.10 * tv.volumeMm3) << describe(tv);
        }
        EXPECT_EQ(hit->kind, tv.kind == "crack" ? "crack" : "pore") << describe(tv) << " flatness-classified";
        EXPECT_NEAR(hit->maxExtentMm, tv.maxExtentMm, 2.0 * vox) << describe(tv);
        EXPECT_GT(hit->distanceToSurfaceMm, 4.0 * vox) << describe(tv) << ": voids keep >= 4 voxels of material";
        if (tv.kind == "crack") {
            EXPECT_LT(hit->sphericity, 0.6) << describe(tv);
        } else {
            EXPECT_GT(hit->sphericity, 0.7) << describe(tv);
            EXPECT_LT(hit->sphericity, 1.1) << describe(tv);
        }
    }
    EXPECT_EQ(static_cast<int>(a.voids.size()), internal) << "listed voids vs internal truth voids";
    EXPECT_NEAR(a.porosityPercent, t.porosityPercent, 0.01) << "porosity (percentage points)";
    EXPECT_NEAR(a.materialVolumeMm3, t.materialVolumeMm3, 1e-3 * t.materialVolumeMm3);
    EXPECT_NEAR(a.voidVolumeMm3, t.internalVoidVolumeMm3, 0.01 * t.internalVoidVolumeMm3);
    (void)vox3;
}

} // namespace

TEST(PartPhantom, TruthFollowsTheShapes)
{
    PartPhantomParams p;  // 128^3
    const Generated g = generate(p);
    const PartTruth& t = g.truth;
    ASSERT_EQ(t.voids.size(), 14u) << "12 pores, a crack, an open crack";
    int cracks = 0, open = 0, elongated = 0, spheres = 0;
    double minD = 1e9, maxD = 0;
    const double vox3 = std::pow(p.voxelMm, 3);
    for (const PartVoidTruth& v : t.voids) {
        const Vec3d ax = v.semiAxesVoxels;
        if (v.kind == "crack") {
            ++cracks;
            EXPECT_TRUE(v.internal);
            EXPECT_NEAR(v.volumeMm3, PI * ax.x * ax.y * 2 * ax.z * vox3, 0.03 * PI * ax.x * ax.y * 2 * ax.z * vox3);
        } else if (v.kind == "open_crack") {
            ++open;
            EXPECT_FALSE(v.internal);
            EXPECT_LT(v.volumeMm3, 0.75 * PI * ax.x * ax.y * 2 * ax.z * vox3) << "part of it lies outside the part";
            EXPECT_GT(v.volumeMm3, 0.25 * PI * ax.x * ax.y * 2 * ax.z * vox3);
        } else {
            ASSERT_EQ(v.kind, "pore");
            (ax.x > ax.y + 1e-9 ? elongated : spheres)++;
            minD = std::min(minD, 2 * ax.y);
            maxD = std::max(maxD, 2 * ax.x);
            const double analytic = 4.0 / 3.0 * PI * ax.x * ax.y * ax.z * vox3;
            // exact partial volume up to the 4^3 samples of boundary voxels
            EXPECT_NEAR(v.volumeMm3, analytic, (2 * ax.y >= 4 ? 0.04 : 0.12) * analytic) << describe(v);
            EXPECT_NEAR(v.equivalentDiameterMm, equivalentDiameter(v.volumeMm3), 1e-12);
            EXPECT_LE(v.maxExtentMm, (2 * ax.x + 1) * p.voxelMm);  // counted voxels' centres may poke out
            EXPECT_GE(v.maxExtentMm, (2 * ax.x - 2) * p.voxelMm);
        }
        if (v.internal) {
            EXPECT_LT(distance(v.centroidLps, v.centerLps), 0.3 * p.voxelMm) << describe(v);
        }
    }
    EXPECT_EQ(cracks, 1);
    EXPECT_EQ(open, 1);
    EXPECT_EQ(spheres, 6);
    EXPECT_EQ(elongated, 6);
    EXPECT_NEAR(minD, 3.0, 1e-9);
    EXPECT_NEAR(maxD, 16.0, 1e-9);
    // material: body + flange - bore - internal voids (analytic), partial volume exact to ~0.1%
    const double n = p.size;
    const double analyticPart = PI * ((0.34 * n) * (0.34 * n) * 0.8 * n + ((0.46 * n) * (0.46 * n) - (0.34 * n) * (0.34 * n)) * 0.12 * n -
                                      (0.08 * n) * (0.08 * n) * 0.8 * n) * vox3;
    double openCrack = 0;
    for (const PartVoidTruth& v : t.voids)
        if (!v.internal) openCrack = v.volumeMm3;
    EXPECT_NEAR(t.materialVolumeMm3 + t.internalVoidVolumeMm3 + openCrack, analyticPart, 0.002 * analyticPart);
    EXPECT_NEAR(t.porosityPercent, 100 * t.internalVoidVolumeMm3 / (t.materialVolumeMm3 + t.internalVoidVolumeMm3), 1e-12);
    // grey values: air far from the part, material in the middle of the wall
    const auto at = [&](int i, int j, int k) { return g.voxels[(static_cast<std::size_t>(k) * p.size + j) * p.size + i]; };
    double air = 0, mat = 0;
    for (int i = 0; i < 100; ++i) {
        air += at(2 + i % 10, 2 + i / 10, 2);
        mat += at(64 + 28 + i % 5, 64 + i / 20, 30 + i % 3);
    }
    EXPECT_NEAR(air / 100, p.airGrey, 0.02 * (p.materialGrey - p.airGrey));
    EXPECT_NEAR(mat / 100, p.materialGrey, 0.03 * (p.materialGrey - p.airGrey));
}

TEST(PartPhantom, StreamsNiftiAndNrrdThatReadBack)
{
    PartPhantomParams p;
    p.size = 112;
    p.seed = 3;
    p.pores = 4;
    const Generated g = generate(p);
    const fs::path dir = fs::temp_directory_path() / ("flyover_part_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    for (const std::string name : {"part.nii.gz", "part.nii", "part.nrrd"}) {
        const std::string path = (dir / name).string();
        const PartTruth t = writePartPhantom(p, path, (dir / "truth.json").string());
        EXPECT_EQ(t.porosityPercent, g.truth.porosityPercent) << "deterministic";
        const Image3<float> img = readImage(path);
        ASSERT_EQ(img.geometry.size[0], 112) << path;
        ASSERT_EQ(img.geometry.size[2], 112) << path;
        EXPECT_NEAR(img.geometry.spacingMm.x, 0.1, 1e-6) << path;
        EXPECT_NEAR(img.geometry.originMm.x, -5.55, 1e-4) << path << " (LPS origin)";
        EXPECT_NEAR(img.geometry.originMm.y, -5.55, 1e-4) << path;
        EXPECT_NEAR(img.geometry.originMm.z, -5.55, 1e-4) << path;
        EXPECT_NEAR(img.geometry.direction[0][0], 1.0, 1e-6) << path << " (LPS identity direction)";
        EXPECT_NEAR(img.geometry.direction[1][1], 1.0, 1e-6) << path;
        std::size_t differ = 0;
        for (std::size_t i = 0; i < g.voxels.size(); ++i) differ += img.voxels[i] != static_cast<float>(g.voxels[i]);
        EXPECT_EQ(differ, 0u) << path << ": voxels differ from the generated slices";
    }
    const nlohmann::json j = readJson((dir / "truth.json").string());
    EXPECT_EQ(j.at("schema"), "flyover.part_truth/1");
    EXPECT_EQ(j.at("world_frame"), "LPS");
    EXPECT_EQ(j.at("voids").size(), 6u);
    EXPECT_DOUBLE_EQ(j.at("porosity_percent").get<double>(), g.truth.porosityPercent);
    for (const auto& v : j.at("voids")) {
        EXPECT_TRUE(v.contains("centroid_lps_mm") && v.contains("volume_mm3") && v.contains("equivalent_diameter_mm") &&
                    v.contains("max_extent_mm") && v.contains("internal") && v.contains("kind"));
    }
    for (const auto& e : fs::directory_iterator(dir))
        EXPECT_EQ(e.path().filename().string().rfind(".tmp", 0), std::string::npos) << "temporary left: " << e.path();
    fs::remove_all(dir);
}

TEST(PartPhantom, RejectsBadParameters)
{
    const auto sink = [](int64_t, const std::vector<uint16_t>&) {};
    PartPhantomParams p;
    p.size = 100;
    EXPECT_THROW(generatePartPhantom(p, sink), ParameterError);
    p = PartPhantomParams{};
    p.materialGrey = p.airGrey;
    EXPECT_THROW(generatePartPhantom(p, sink), ParameterError);
    p = PartPhantomParams{};
    p.materialGrey = 70000;
    EXPECT_THROW(generatePartPhantom(p, sink), ParameterError);
    EXPECT_THROW(parsePartSize("12x"), ParameterError);
    EXPECT_THROW(parsePartSize("4096"), ParameterError);
    EXPECT_EQ(parsePartSize("1024"), 1024);
    EXPECT_THROW(writePartPhantom(PartPhantomParams{}, "/tmp/part.png", ""), ParameterError);
    EXPECT_THROW(writePartPhantom(PartPhantomParams{}, "/nonexistent/dir/part.nii", ""), InputError);
}

TEST(PartAnalysis, FindsEveryTruthVoid)
{
    const Generated g = generate(PartPhantomParams{});
    const PartAnalysis a = analysePart(*toGrid(g), VoidParams{}, "part128.nii");
    expectAnalysisMatchesTruth(g, a);
}

TEST(PartAnalysis, AnyGreyRangeAndSeed)
{
    PartPhantomParams p;
    p.size = 160;
    p.seed = 11;
    p.airGrey = 300;
    p.materialGrey = 1500;  // a 12-bit-like range
    const Generated g = generate(p);
    const PartAnalysis a = analysePart(*toGrid(g), VoidParams{}, "part160.nrrd");
    expectAnalysisMatchesTruth(g, a);
}

TEST(PartAnalysis, SparseGridWithGreyBackgroundGivesTheSameAnswer)
{
    const Generated g = generate(PartPhantomParams{});
    const auto dense = toGrid(g), sparse = toGrid(g, true);
    ASSERT_LT(sparse->activeVoxelCount(), dense->activeVoxelCount() * 3 / 4);
    const PartAnalysis a = analysePart(*sparse, VoidParams{}, "sparse.nii");
    expectAnalysisMatchesTruth(g, a);
}

TEST(PartPhantom, InterruptedWriteLeavesNoFile)
{
    struct CancelAfter : Progress {
        int calls = 0;
        void update(double, const std::string&) override { ++calls; }
        bool cancelled() const override { return calls >= 2; }  // after the first slices
    } cancel;
    const fs::path dir = fs::temp_directory_path() / ("flyover_part_cancel_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const std::string path = (dir / "part.nii").string();
    EXPECT_THROW(writePartPhantom(PartPhantomParams{}, path, (dir / "truth.json").string(), &cancel), Cancelled);
    EXPECT_FALSE(fs::exists(path)) << "a half-written volume under the final name";
    EXPECT_FALSE(fs::exists(dir / "truth.json"));
    EXPECT_TRUE(fs::is_empty(dir)) << "temporary files left in " << dir;
    fs::remove_all(dir);
}
