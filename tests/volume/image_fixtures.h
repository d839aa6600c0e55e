// The image fixtures in data/fixtures/ (made by scripts/make_fixtures.sh) and the analytic
// model behind them, shared by image_io_test.cpp and ingest_test.cpp.
#pragma once

#include "tests/volume/shared_data.h"
#include "volume/image.h"

#include <cmath>
#include <string>

namespace flyover::test {

inline std::string fixture(const std::string& name) { return std::string(FLYOVER_SOURCE_DIR) + "/data/fixtures/" + name; }

/// The real CT of the shared data (20 DICOM slices, full NIfTI), when this machine has it
/// (a path that does not exist when it has not).
inline std::string sharedReal(const std::string& name)
{
    const std::string dir = sharedDataDir();
    return (dir.empty() ? "(no shared/data above " + std::string(FLYOVER_SOURCE_DIR) + ")" : dir) +
           "/real/totalsegmentator-example/" + name;
}

// The test volume every good fixture holds (scripts/fixtures/make_fixtures.cpp).
inline constexpr int64_t FX_NX = 20, FX_NY = 16, FX_NZ = 10;
inline constexpr double FX_SPACING[3] = {0.75, 0.625, 1.5};
inline constexpr Vec3d FX_ORIGIN{-12.5, 30.25, -40.0};

/// Rz(20 deg) * Rx(10 deg); columns are the LPS directions of i, j, k.
inline Mat3d fixtureDirection()
{
    const double pi = 3.14159265358979323846;
    const double a = 20 * pi / 180, b = 10 * pi / 180;
    const Mat3d rz{{{std::cos(a), -std::sin(a), 0}, {std::sin(a), std::cos(a), 0}, {0, 0, 1}}};
    const Mat3d rx{{{1, 0, 0}, {0, std::cos(b), -std::sin(b)}, {0, std::sin(b), std::cos(b)}}};
    Mat3d m{};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            m[r][c] = 0;
            for (int k = 0; k < 3; ++k) m[r][c] += rz[r][k] * rx[k][c];
        }
    return m;
}

inline ImageGeometry fixtureGeometry()
{
    ImageGeometry g;
    g.size = {FX_NX, FX_NY, FX_NZ};
    g.spacingMm = {FX_SPACING[0], FX_SPACING[1], FX_SPACING[2]};
    g.originMm = FX_ORIGIN;
    g.direction = fixtureDirection();
    return g;
}

/// HU inside the body: linear in the world position (LPS mm), so trilinear resampling
/// reproduces it exactly wherever the input slices really are.
inline double fixtureBodyHu(const Vec3d& p) { return 200.0 + 3.0 * p.x - 2.0 * p.y + 4.0 * p.z; }

/// The body's elliptic cross-section in slice index coordinates, shrunk by `marginVoxels`.
inline bool insideFixtureBody(double i, double j, double marginVoxels = 0.0)
{
    const double x = (i - 9.5) / (7.0 - marginVoxels), y = (j - 7.5) / (5.0 - marginVoxels);
    return x * x + y * y <= 1.0;
}

/// The enclosed gas pocket (-1000 HU inside the body).
inline bool insideFixturePocket(int64_t i, int64_t j, int64_t k) { return i >= 9 && i <= 10 && j == 7 && k >= 3 && k <= 6; }

} // namespace flyover::test
