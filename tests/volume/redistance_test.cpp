// detail::redistance() (volume/redistance.cpp) against openvdb::tools::sdfToSdf, which it
// replaces: the same values bit for bit, on any number of threads.
#include "volume/segment_tools.h"

#include <gtest/gtest.h>

#include <openvdb/tools/FastSweeping.h>

#include <tbb/task_arena.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <sstream>
#include <string>

namespace flyover {
namespace {

using openvdb::Coord;
using openvdb::FloatGrid;
using openvdb::FloatTree;

std::uint32_t bits(float v)
{
    std::uint32_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}

/// Every difference between two grids: active topology, each voxel's and tile's value (bits)
/// and the background. Empty when identical.
std::string differences(const FloatGrid& expected, const FloatGrid& seen)
{
    std::ostringstream out;
    int reported = 0;
    auto report = [&](const std::string& what) {
        if (reported++ < 8) out << what << "\n";
    };
    if (bits(expected.background()) != bits(seen.background()))
        report("background: expected " + std::to_string(expected.background()) + ", seen " +
               std::to_string(seen.background()));
    if (expected.activeVoxelCount() != seen.activeVoxelCount())
        report("active voxels: expected " + std::to_string(expected.activeVoxelCount()) + ", seen " +
               std::to_string(seen.activeVoxelCount()));
    openvdb::tree::ValueAccessor<const FloatTree> seenAcc(seen.tree());
    for (auto it = expected.tree().cbeginValueAll(); it; ++it) {
        const Coord ijk = it.getCoord();
        const float want = *it;
        float got = 0;
        const bool on = seenAcc.probeValue(ijk, got);
        if (on != it.isValueOn() || bits(want) != bits(got)) {
            std::ostringstream s;
            s.precision(9);
            s << (it.isVoxelValue() ? "voxel " : "tile ") << ijk << ": expected " << want
              << (it.isValueOn() ? " (active)" : " (inactive)") << ", seen " << got << (on ? " (active)" : " (inactive)");
            report(s.str());
        }
    }
    if (reported > 8) out << "... " << reported << " differences in all\n";
    return out.str();
}

/// What redistance() replaces, with its zero rule (exact zeros are outside).
FloatGrid::Ptr reference(const FloatGrid& f)
{
    FloatGrid::Ptr copy = f.deepCopy();
    for (auto it = copy->tree().beginValueOn(); it; ++it)
        if (*it == 0.0f) it.setValue(std::numeric_limits<float>::min());
    return openvdb::tools::sdfToSdf(*copy, 0.0f, 1);
}

FloatGrid::Ptr ours(const FloatGrid& f, int threads)
{
    FloatGrid::Ptr copy = f.deepCopy();
    FloatGrid::Ptr out;
    tbb::task_arena arena(threads);
    arena.execute([&] { out = detail::redistance(*copy); });
    return out;
}

void expectSameAsSdfToSdf(const FloatGrid& f)
{
    const FloatGrid::Ptr want = reference(f);
    for (int threads : {1, 2, 4}) {
        const FloatGrid::Ptr got = ours(f, threads);
        EXPECT_EQ(differences(*want, *got), "") << "with " << threads << " thread(s)";
    }
}

/// A lumen-like field as segmentLumen() builds it: HU - iso (noisy) on two air tubes that
/// nearly touch and a small pocket, dilated by a shell; some deep voxels inactive (as the
/// mask path leaves them), inactive leaves and a forced-outside background.
FloatGrid::Ptr noisyTubes(std::uint64_t seed, double voxelMm)
{
    std::mt19937_64 rng(seed);
    std::normal_distribution<float> noise(0.0f, 40.0f);
    auto grid = FloatGrid::create(500.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelMm));
    auto acc = grid->getAccessor();
    auto airAt = [](int i, int j, int k) {
        const double r1 = std::hypot(i - 20.3, j - 21.6), r2 = std::hypot(i - 37.7, k - 30.2);
        const double r3 = std::sqrt((i - 50.0) * (i - 50.0) + (j - 50.0) * (j - 50.0) + (k - 12.0) * (k - 12.0));
        return r1 < 7.5 || (r2 < 9.2 && j > 4 && j < 56) || r3 < 3.1;
    };
    for (int i = 0; i < 64; ++i)
        for (int j = 0; j < 64; ++j)
            for (int k = 0; k < 64; ++k) {
                bool nearAir = false;
                for (int d = -3; d <= 3 && !nearAir; ++d)
                    nearAir = airAt(i + d, j, k) || airAt(i, j + d, k) || airAt(i, j, k + d);
                if (!nearAir) continue;
                const float hu = airAt(i, j, k) ? -1000.0f : 40.0f;
                float v = hu + noise(rng) + 480.0f;
                if ((i + j + k) % 97 == 0) v = 0.0f;  // exact iso-values
                acc.setValue(Coord(i, j, k), v);
            }
    // Deep voxels inactive with their values kept.
    for (int i = 18; i < 23; ++i)
        for (int j = 19; j < 24; ++j)
            for (int k = 10; k < 50; ++k) acc.setValueOff(Coord(i, j, k));
    // An inactive leaf next to the region, holding negative values (an inside reading there).
    for (int i = 64; i < 72; ++i)
        for (int j = 16; j < 24; ++j)
            for (int k = 16; k < 24; ++k) acc.setValueOff(Coord(i, j, k), -300.0f);
    return grid;
}

/// A binary mask's field 0.5 - indicator on a ball (ties everywhere), and an inactive inside
/// tile next to it.
FloatGrid::Ptr binaryBall()
{
    auto grid = FloatGrid::create(0.5f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.7));
    auto acc = grid->getAccessor();
    for (int i = -20; i <= 20; ++i)
        for (int j = -20; j <= 20; ++j)
            for (int k = -20; k <= 20; ++k) {
                const double r = std::sqrt(double(i * i + j * j + k * k));
                if (r < 19.0) acc.setValue(Coord(i, j, k), r < 14.2 ? -0.5f : 0.5f);
            }
    grid->tree().addTile(1, Coord(64, 0, 0), -0.5f, false);
    return grid;
}

TEST(Redistance, SameAsSdfToSdfOnNoisyTubes)
{
    for (std::uint64_t seed : {1u, 2u}) {
        SCOPED_TRACE("seed " + std::to_string(seed));
        expectSameAsSdfToSdf(*noisyTubes(seed, 0.75));
    }
}

TEST(Redistance, SameAsSdfToSdfOnABinaryBall)
{
    expectSameAsSdfToSdf(*binaryBall());
}

/// A binary torus (tube radius 11 voxels around a 30-voxel circle) in a shell of 6 voxels:
/// thick enough that many leaves stop changing before the eighth sweep and are skipped.
FloatGrid::Ptr binaryTorus()
{
    auto grid = FloatGrid::create(0.5f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.7));
    auto acc = grid->getAccessor();
    for (int i = -48; i <= 48; ++i)
        for (int j = -48; j <= 48; ++j)
            for (int k = -18; k <= 18; ++k) {
                const double ring = std::hypot(double(i), double(j)) - 30.0;
                const double r = std::hypot(ring, double(k) + 0.3);
                if (r < 17.0) acc.setValue(Coord(i, j, k), r < 11.0 ? -0.5f : 0.5f);
            }
    return grid;
}

TEST(Redistance, SameAsSdfToSdfWhenLeavesAreSkipped)
{
    const FloatGrid::Ptr f = binaryTorus();
    FloatGrid::Ptr copy = f->deepCopy();
    std::size_t skipped = 0;
    detail::redistance(*copy, &skipped);
    // Leaves are skipped (else this test would not test the skipping) ...
    EXPECT_GT(skipped, 0u) << "no leaf sweep was skipped on the torus";
    // ... and the values are still those of the full sweeps.
    expectSameAsSdfToSdf(*f);
}

TEST(Redistance, SameAsSdfToSdfWithNothingToSweepFrom)
{
    // No sign change: sdfToSdf returns its initialisation, unswept.
    auto grid = FloatGrid::create(1.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1.0));
    grid->fill(openvdb::CoordBBox(Coord(0), Coord(20)), 3.0f, true);
    grid->tree().voxelizeActiveTiles();
    expectSameAsSdfToSdf(*grid);
}

TEST(Redistance, DistanceToAPlaneIsExact)
{
    // Fast sweeping is exact for a plane: every voxel gets x - 10.3 voxels (h = 0.5 mm). The
    // outermost layer is inactive (values kept), so that no false interface with the background
    // appears at the box's faces.
    auto grid = FloatGrid::create(100.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
    auto acc = grid->getAccessor();
    for (int i = 0; i < 40; ++i)
        for (int j = 0; j < 24; ++j)
            for (int k = 0; k < 24; ++k) {
                const bool edge = i == 0 || i == 39 || j == 0 || j == 23 || k == 0 || k == 23;
                acc.setValue(Coord(i, j, k), float(i) - 10.3f);
                if (edge) acc.setValueOff(Coord(i, j, k));
            }
    const FloatGrid::Ptr sdf = ours(*grid, 2);
    for (auto it = sdf->tree().cbeginValueOn(); it; ++it) {
        const double expected = 0.5 * (it.getCoord().x() - 10.3);
        ASSERT_NEAR(*it, expected, 1e-4) << "at " << it.getCoord();
    }
}

TEST(Redistance, RefusesActiveTiles)
{
    auto grid = FloatGrid::create(1.0f);
    grid->tree().addTile(1, Coord(0), -1.0f, true);
    EXPECT_THROW(detail::redistance(*grid), openvdb::RuntimeError);
}

} // namespace
} // namespace flyover
