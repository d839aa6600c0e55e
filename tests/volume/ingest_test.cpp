// Ingest: identical grids from every format, world positions that land on the scan
// (oblique, anisotropic, gantry-tilted, with gaps), sparse outside air, slab-by-slab reads.

#include "tests/volume/image_fixtures.h"

#include "volume/error.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

using namespace flyover;
using namespace flyover::test;

namespace {

struct Ingested {
    openvdb::FloatGrid::Ptr grid;
    IngestReport report;
};

Ingested ingestFixture(const std::string& name, const IngestParams& params = {})
{
    openvdb::initialize();
    ImageReadOptions options;
    options.dicomSeriesUid = params.dicomSeries;
    options.allowGaps = params.allowGaps;
    auto source = openImage(fixture(name), options);
    Ingested out;
    out.grid = ingestImage(*source, params, &out.report);
    return out;
}

Vec3d worldOf(const openvdb::FloatGrid& grid, const openvdb::Coord& ijk)
{
    const openvdb::Vec3d w = grid.indexToWorld(ijk);
    return {w.x(), w.y(), w.z()};
}

/// Columns of the enclosed gas pocket (and their partial-volume neighbours) are skipped
/// by the value checks: there the HU are not the linear body function.
bool nearPocket(double i, double j) { return std::fabs(i - 9.5) <= 2.5 && std::fabs(j - 7.0) <= 2.0; }

/// Checks every active voxel whose 2x2x2 input neighbourhood lies inside the body against
/// the analytic HU at its world position; `inputIndex` maps a world point to continuous
/// (i, j) in its slice and k. Returns the number checked.
template <typename ToInput>
int expectBodyHuAtWorldPositions(const openvdb::FloatGrid& grid, ToInput&& inputIndex, const std::string& what)
{
    int checked = 0, bad = 0;
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        const Vec3d p = worldOf(grid, it.getCoord());
        const Vec3d c = inputIndex(p);
        if (!insideFixtureBody(c.x, c.y, 1.5) || nearPocket(c.x, c.y) || c.z < 0 || c.z > double(FX_NZ - 1)) continue;
        ++checked;
        // Stored values are round(f) at input voxel centres; interpolating them stays within 0.5 HU of f.
        if (std::fabs(*it - fixtureBodyHu(p)) > 0.5 + 1e-3 && bad++ < 5)
            ADD_FAILURE() << what << ": voxel " << it.getCoord() << " at LPS (" << p.x << ", " << p.y << ", " << p.z
                          << ") holds " << *it << " HU, the scan has " << fixtureBodyHu(p);
    }
    EXPECT_EQ(bad, 0) << what;
    return checked;
}

/// A synthetic source that records how it is read.
class CountingSource : public ImageSource {
public:
    CountingSource(int64_t n, int64_t nk, double sliceMm)
    {
        mName = "counting";
        mGeometry.size = {n, n, nk};
        mGeometry.spacingMm = {1.0, 1.0, sliceMm};
        reads.assign(static_cast<std::size_t>(nk), 0);
    }
    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const int64_t n = mGeometry.size[0];
        maxSlicesPerCall = std::max(maxSlicesPerCall, k1 - k0);
        increasing = increasing && k0 >= lastK1;
        lastK1 = k1;
        for (int64_t k = k0; k < k1; ++k) {
            ++reads[static_cast<std::size_t>(k)];
            for (int64_t j = 0; j < n; ++j)
                for (int64_t i = 0; i < n; ++i) {
                    const double dx = double(i) - n / 2.0, dy = double(j) - n / 2.0;
                    *out++ = dx * dx + dy * dy < n * n / 9.0 ? 40.0f : -1000.0f;
                }
        }
    }
    std::vector<int> reads;
    int64_t maxSlicesPerCall = 0, lastK1 = 0;
    bool increasing = true;
};

} // namespace

TEST(Ingest, SameVolumeInEveryFormatGivesIdenticalGrids)
{
    const Ingested ref = ingestFixture("same.nii");
    ASSERT_GT(ref.grid->activeVoxelCount(), 2000u);
    for (const char* name : {"same.nii.gz", "same_scaled.nii", "same.nrrd", "same.nhdr", "same.mha", "same_zlib.mha",
                             "same.mhd", "same_nifti2.nii", "dicom/same", "dicom/same_j2k", "dicom/same_jpegll"}) {
        const Ingested got = ingestFixture(name);
        EXPECT_EQ(got.grid->activeVoxelCount(), ref.grid->activeVoxelCount()) << name;
        EXPECT_EQ(got.report.gridSize, ref.report.gridSize) << name;
        auto acc = got.grid->getConstAccessor();
        std::size_t differing = 0;
        for (auto it = ref.grid->cbeginValueOn(); it; ++it) {
            const openvdb::Coord& c = it.getCoord();
            if (!acc.isValueOn(c) || acc.getValue(c) != *it) ++differing;
            // World positions: same millimetres (NIfTI holds its affine in float32).
            if ((c.x() + c.y() + c.z()) % 17 == 0) {
                ASSERT_LT(distance(worldOf(*got.grid, c), worldOf(*ref.grid, c)), 1e-4) << name << " at " << c;
            }
        }
        EXPECT_EQ(differing, 0u) << name;
    }
}

TEST(Ingest, AnisotropicObliqueScanLandsAtItsWorldPositions)
{
    const Ingested got = ingestFixture("same.nii");
    EXPECT_DOUBLE_EQ(got.report.voxelMm, 0.625) << "default: the smallest spacing";
    EXPECT_NE(got.report.interpolation.find("trilinear"), std::string::npos);
    // Index (0,0,0) is the input's voxel (0,0,0) centre; axes follow the direction cosines.
    EXPECT_LT(distance(worldOf(*got.grid, openvdb::Coord(0, 0, 0)), FX_ORIGIN), 1e-4);
    const ImageGeometry g = fixtureGeometry();
    EXPECT_LT(distance(worldOf(*got.grid, openvdb::Coord(8, 0, 0)), g.worldFromIndex({8 * 0.625 / 0.75, 0, 0})), 1e-4);
    EXPECT_LT(distance(worldOf(*got.grid, openvdb::Coord(0, 0, 12)), g.worldFromIndex({0, 0, 12 * 0.625 / 1.5})), 1e-4);
    const int checked = expectBodyHuAtWorldPositions(
        *got.grid, [&](const Vec3d& p) { return g.indexFromWorld(p); }, "same.nii");
    EXPECT_GT(checked, 1000);
}

TEST(Ingest, IsotropicInputIsCopiedWithoutInterpolation)
{
    openvdb::initialize();
    Image3<float> img;
    img.geometry.size = {24, 20, 12};
    img.geometry.spacingMm = {0.8, 0.8, 0.8};
    img.geometry.originMm = {10, -20, 30};
    img.geometry.direction = fixtureDirection();
    img.voxels.assign(static_cast<std::size_t>(img.geometry.voxelCount()), -1000.0f);
    for (int64_t k = 0; k < 12; ++k)
        for (int64_t j = 3; j < 17; ++j)
            for (int64_t i = 3; i < 21; ++i) img.at(i, j, k) = float(i * 7 + j * 3 - k) + 0.25f;
    IngestReport rep;
    const auto grid = ingestImage(img, IngestParams{}, &rep);
    EXPECT_NE(rep.interpolation.find("none"), std::string::npos) << rep.interpolation;
    EXPECT_EQ(grid->activeVoxelCount(), 12u * 14u * 18u);
    auto acc = grid->getConstAccessor();
    for (int64_t k = 0; k < 12; ++k)
        for (int64_t j = 3; j < 17; ++j)
            for (int64_t i = 3; i < 21; ++i) {
                const openvdb::Coord c{static_cast<int>(i), static_cast<int>(j), static_cast<int>(k)};
                ASSERT_EQ(acc.getValue(c), img.at(i, j, k)) << c;
                ASSERT_LT(distance(worldOf(*grid, c), img.geometry.worldFromIndex({double(i), double(j), double(k)})), 1e-9);
            }
    // The leaves are built row by row of the slab: every voxel of the lattice (partial leaves
    // at the +x, +y, +z ends included) is active exactly inside the body, outside it holds the
    // background, and there is one leaf per 8^3 block holding body voxels (x: 0-23 -> 3 blocks,
    // y: 3-16 -> 3, z: 0-11 -> 2).
    EXPECT_EQ(grid->tree().leafCount(), 3u * 3u * 2u);
    for (int k = 0; k < 12; ++k)
        for (int j = 0; j < 20; ++j)
            for (int i = 0; i < 24; ++i) {
                const openvdb::Coord c{i, j, k};
                const bool body = i >= 3 && i < 21 && j >= 3 && j < 17;
                ASSERT_EQ(acc.isValueOn(c), body) << "voxel " << c << ": expected " << (body ? "active" : "inactive");
                if (!body) {
                    ASSERT_EQ(acc.getValue(c), -1000.0f) << "voxel " << c << " outside the body";
                }
            }
}

TEST(Ingest, VoxelSizeParameterSetsTheLattice)
{
    IngestParams p;
    p.voxelMm = 1.0;
    const Ingested got = ingestFixture("same.mha", p);
    // Extents of voxel centres: 19 * 0.75, 15 * 0.625, 9 * 1.5 mm.
    EXPECT_EQ(got.report.gridSize, (std::array<int64_t, 3>{15, 10, 14}));
    EXPECT_NEAR(got.grid->voxelSize().x(), 1.0, 1e-12);
    p.voxelMm = -1;
    EXPECT_THROW(ingestFixture("same.mha", p), ParameterError);
    p.voxelMm = 1e-5;
    EXPECT_THROW(ingestFixture("same.mha", p), ParameterError);
}

TEST(Ingest, OutsideAirIsInactiveAndEnclosedGasStaysActive)
{
    const Ingested got = ingestFixture("same.nii");
    const ImageGeometry g = fixtureGeometry();
    auto acc = got.grid->getConstAccessor();
    const openvdb::Vec3d pocket = got.grid->worldToIndex(openvdb::Vec3d(
        g.worldFromIndex({9.5, 7, 4.5}).x, g.worldFromIndex({9.5, 7, 4.5}).y, g.worldFromIndex({9.5, 7, 4.5}).z));
    const openvdb::Coord pc(int(std::lround(pocket.x())), int(std::lround(pocket.y())), int(std::lround(pocket.z())));
    EXPECT_TRUE(acc.isValueOn(pc));
    EXPECT_LT(acc.getValue(pc), -900.0f);
    EXPECT_FALSE(acc.isValueOn(openvdb::Coord(0, 0, 0)));
    EXPECT_EQ(acc.getValue(openvdb::Coord(0, 0, 0)), -1000.0f);
    for (auto it = got.grid->cbeginValueOn(); it; ++it) {
        const Vec3d c = g.indexFromWorld(worldOf(*got.grid, it.getCoord()));
        ASSERT_TRUE(insideFixtureBody(c.x, c.y, -1.0)) << "active voxel outside the body at " << it.getCoord();
    }
    EXPECT_GT(got.report.memoryBytes, 0);
    EXPECT_EQ(got.report.sourceHeldBytes, 0) << "uncompressed NIfTI streams";
}

TEST(Ingest, OutsideAirMatchesABreadthFirstFillOnEverySlice)
{
    // Random air and tissue (55% air: long winding channels of outside air that the scanline
    // fill must follow up and down and back), 67 x 53 x 11 voxels of 1 mm (copied, not
    // interpolated). Expected: per slice, the air 4-connected to the slice border, found by a
    // plain breadth-first fill, is inactive background; every other voxel is active with its
    // value.
    Image3<float> image;
    image.geometry.size = {67, 53, 11};
    image.geometry.spacingMm = {1, 1, 1};
    image.voxels.resize(67 * 53 * 11);
    uint32_t state = 7;
    for (float& v : image.voxels) {
        state = state * 1664525u + 1013904223u;
        v = (state >> 8) % 100 < 55 ? -1000.0f + float(state % 7) : 40.0f + float(state % 13);
    }
    const auto grid = ingestImage(image, IngestParams{});
    auto acc = grid->getConstAccessor();
    const int nx = 67, ny = 53;
    std::size_t outside = 0, wrong = 0;
    for (int z = 0; z < 11; ++z) {
        const float* slice = image.voxels.data() + std::size_t(z) * nx * ny;
        std::vector<char> reached(std::size_t(nx) * ny, 0);
        std::vector<std::pair<int, int>> queue;
        auto visit = [&](int x, int y) {
            const std::size_t i = std::size_t(y) * nx + x;
            if (x < 0 || y < 0 || x >= nx || y >= ny || reached[i] || !(slice[i] < -500.0f)) return;
            reached[i] = 1;
            queue.emplace_back(x, y);
        };
        for (int x = 0; x < nx; ++x) visit(x, 0), visit(x, ny - 1);
        for (int y = 0; y < ny; ++y) visit(0, y), visit(nx - 1, y);
        for (std::size_t q = 0; q < queue.size(); ++q) {
            const auto [x, y] = queue[q];
            visit(x - 1, y), visit(x + 1, y), visit(x, y - 1), visit(x, y + 1);
        }
        outside += queue.size();
        for (int y = 0; y < ny; ++y)
            for (int x = 0; x < nx; ++x) {
                const std::size_t i = std::size_t(y) * nx + x;
                const openvdb::Coord c(x, y, z);
                const bool on = acc.isValueOn(c);
                const float want = reached[i] ? -1000.0f : slice[i];
                if (on == bool(reached[i]) || acc.getValue(c) != want) {
                    if (wrong++ < 5)
                        ADD_FAILURE() << "voxel " << c << ": expected " << (reached[i] ? "inactive" : "active") << " "
                                      << want << ", got " << (on ? "active " : "inactive ") << acc.getValue(c);
                }
            }
    }
    EXPECT_EQ(wrong, 0u);
    EXPECT_GT(outside, std::size_t(67 * 53 * 11 / 10)) << "the pattern has outside air to find";
    EXPECT_LT(outside, std::size_t(67 * 53 * 11 * 55 / 100)) << "and inner air that stays";
}

TEST(Ingest, GantryTiltIsCorrectedByResamplingAtTrueSlicePositions)
{
    const Ingested got = ingestFixture("dicom/tilt");
    ASSERT_EQ(got.report.warnings.size(), 1u);
    EXPECT_NE(got.report.warnings[0].find("gantry tilt of 15 degrees"), std::string::npos) << got.report.warnings[0];
    // Slice k's pixel (i, j) lies at origin + k*1.5*(n + tan(15 deg) v) + i*0.75 u + j*0.625 v.
    const ImageGeometry g = fixtureGeometry();
    const Vec3d u{g.direction[0][0], g.direction[1][0], g.direction[2][0]};
    const Vec3d v{g.direction[0][1], g.direction[1][1], g.direction[2][1]};
    const Vec3d n{g.direction[0][2], g.direction[1][2], g.direction[2][2]};
    const double shear = std::tan(15 * 3.14159265358979323846 / 180);
    auto inputIndex = [&](const Vec3d& p) {
        const Vec3d d = p - FX_ORIGIN;
        const double t = dot(d, n);
        return Vec3d{dot(d, u) / 0.75, (dot(d, v) - t * shear) / 0.625, t / 1.5};
    };
    const int checked = expectBodyHuAtWorldPositions(*got.grid, inputIndex, "dicom/tilt");
    EXPECT_GT(checked, 1000);
    // The grid grew sideways to hold every slice's footprint (13.5 mm * tan 15 deg = 3.6 mm).
    EXPECT_EQ(got.report.gridSize[0], 23);
    EXPECT_GT(got.report.gridSize[1], 16);
}

TEST(Ingest, AcceptedGapsAreInterpolatedAtTrueSlicePositions)
{
    IngestParams p;
    p.allowGaps = true;
    const ImageGeometry g = fixtureGeometry();
    for (const char* name : {"bad/dicom/missing_slice", "bad/dicom/uneven"}) {
        const Ingested got = ingestFixture(name, p);
        ASSERT_EQ(got.report.warnings.size(), 1u) << name;
        const int checked = expectBodyHuAtWorldPositions(
            *got.grid, [&](const Vec3d& w) { return g.indexFromWorld(w); }, name);
        EXPECT_GT(checked, 1000) << name;
    }
    EXPECT_THROW(ingestFixture("bad/dicom/missing_slice"), InputError);
}

TEST(Ingest, ReadsEachInputSliceOnceSlabBySlab)
{
    openvdb::initialize();
    for (double sliceMm : {1.0, 2.5}) {
        CountingSource source(48, 100, sliceMm);
        IngestReport rep;
        const auto grid = ingestImage(source, IngestParams{}, &rep);
        for (std::size_t k = 0; k < source.reads.size(); ++k) ASSERT_EQ(source.reads[k], 1) << "slice " << k;
        EXPECT_TRUE(source.increasing);
        EXPECT_LE(source.maxSlicesPerCall, 9) << "one slab of 8 output slices and the next input slice";
        const int64_t slab = 48 * 48 * 8;
        EXPECT_LE(rep.workingBytes, (9 + 8) * 48 * 48 * 4 + slab) << "buffers stay within one slab";
        EXPECT_GT(grid->activeVoxelCount(), 0u);
    }
}

TEST(Ingest, AllAirImageIsRefused)
{
    openvdb::initialize();
    Image3<float> img;
    img.geometry.size = {8, 8, 4};
    img.voxels.assign(256, -1000.0f);
    EXPECT_THROW(ingestImage(img, IngestParams{}), InputError);
}

TEST(Ingest, RealDicomAndNiftiLandOnTheirScannerFrames)
{
    const Ingested dcm = ingestFixture("real/dicom");
    EXPECT_DOUBLE_EQ(dcm.report.voxelMm, 0.9765625);
    EXPECT_EQ(dcm.report.gridSize, (std::array<int64_t, 3>{512, 512, 5}));  // 4 mm of slices at 0.977 mm
    EXPECT_LT(distance(worldOf(*dcm.grid, openvdb::Coord(0, 0, 0)), Vec3d(-249.51171875, -437.51171875, -770.5)), 1e-9);
    EXPECT_LT(distance(worldOf(*dcm.grid, openvdb::Coord(511, 0, 4)),
                       Vec3d(-249.51171875 + 511 * 0.9765625, -437.51171875, -770.5 + 4 * 0.9765625)), 1e-9);
    EXPECT_GT(dcm.grid->activeVoxelCount(), 300000u);
    EXPECT_LT(dcm.grid->activeVoxelCount(), 5u * 512u * 512u * 6u / 10u) << "outside air is inactive";

    const Ingested nii = ingestFixture("real/example_ct_sm_8slices.nii.gz");
    EXPECT_DOUBLE_EQ(nii.report.voxelMm, 3.0);
    EXPECT_NE(nii.report.interpolation.find("none"), std::string::npos);
    EXPECT_LT(distance(worldOf(*nii.grid, openvdb::Coord(10, 20, 5)),
                       Vec3d(-(30 - 177.95632934570312), -(60 + 11.319000244140625), 15 + 94.3017578125)), 1e-9);
}
