// A small industrial-CT test part for the inspect tests: a cylinder with a through bore along
// z, three spherical pores and a thin flat internal crack, partial-volume edges and noise,
// uint16 grey values; written as NRRD by hand (a real format, read by ITK's NrrdImageIO), and
// the truth as an analysis built from the shapes alone (not by analysePart).
#pragma once

#include "volume/image.h"
#include "volume/ingest.h"
#include "volume/vec3.h"
#include "inspect/voids.h"

#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace flyover::test {

struct TestVoid {
    Vec3d centreIjk;        ///< voxel index space
    Vec3d semiAxesVoxels;   ///< ellipsoid semi-axes along x, y, z (voxels)
    bool crack = false;
};

struct TestPart {
    ImageGeometry geometry;
    std::vector<uint16_t> grey;
    std::vector<TestVoid> voids;  ///< truth, largest first
    double radius = 0, boreRadius = 0, zLo = 0, zHi = 0;
    double material = 40000, air = 8000;

    Vec3d centreMm(const TestVoid& v) const { return geometry.worldFromIndex(v.centreIjk); }
    double voxelMm() const { return geometry.spacingMm.x; }

    /// 0 outside air, 1 material, 2 + k inside void k (at a point in index space).
    int classify(const Vec3d& p) const
    {
        const double c = 0.5 * double(geometry.size[0] - 1);
        const double r = std::hypot(p.x - c, p.y - c);
        if (r > radius || r < boreRadius || p.z < zLo || p.z > zHi) return 0;
        for (std::size_t k = 0; k < voids.size(); ++k) {
            const Vec3d d = p - voids[k].centreIjk;
            const Vec3d a = voids[k].semiAxesVoxels;
            if ((d.x * d.x) / (a.x * a.x) + (d.y * d.y) / (a.y * a.y) + (d.z * d.z) / (a.z * a.z) <= 1.0)
                return 2 + int(k);
        }
        return 1;
    }
};

/// An n^3 part (n >= 96) at 0.5 mm, origin (-20, -30, 10) mm.
inline TestPart makeTestPart(int n = 96, uint32_t seed = 7)
{
    TestPart part;
    part.geometry.size = {n, n, n};
    part.geometry.spacingMm = {0.5, 0.5, 0.5};
    part.geometry.originMm = {-20, -30, 10};
    const double c = 0.5 * double(n - 1), s = double(n) / 96.0;
    part.radius = 38 * s;
    part.boreRadius = 9 * s;
    part.zLo = 8 * s;
    part.zHi = double(n) - 9 * s;
    part.voids = {
        {{c + 24 * s, c, 30 * s}, {6 * s, 6 * s, 6 * s}, false},
        {{c, c - 23 * s, 60 * s}, {4 * s, 4 * s, 4 * s}, false},
        {{c - 16 * s, c - 16 * s, 46 * s}, {1.4, 7 * s, 5 * s}, true},  // a thin flat internal crack
        {{c - 20 * s, c + 12 * s, 72 * s}, {2.6 * s, 2.6 * s, 2.6 * s}, false},
    };
    // Partial volume: 4 x 4 x 4 samples per voxel near edges; noise: Gaussian, sigma 600.
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, 600.0);
    part.grey.resize(std::size_t(n) * n * n);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                const int centre = part.classify(Vec3d{double(i), double(j), double(k)});
                bool uniform = true;
                for (int d = 0; d < 8 && uniform; ++d) {
                    const Vec3d q{i + ((d & 1) ? 0.5 : -0.5), j + ((d & 2) ? 0.5 : -0.5), k + ((d & 4) ? 0.5 : -0.5)};
                    uniform = (part.classify(q) == 1) == (centre == 1);
                }
                double fraction = centre == 1 ? 1.0 : 0.0;
                if (!uniform) {
                    int inside = 0;
                    for (int a = 0; a < 4; ++a)
                        for (int b = 0; b < 4; ++b)
                            for (int e = 0; e < 4; ++e)
                                inside += part.classify(Vec3d{i - 0.375 + 0.25 * a, j - 0.375 + 0.25 * b,
                                                              k - 0.375 + 0.25 * e}) == 1;
                    fraction = inside / 64.0;
                }
                const double g = part.air + fraction * (part.material - part.air) + noise(rng);
                part.grey[std::size_t(i) + std::size_t(n) * (std::size_t(j) + std::size_t(n) * std::size_t(k))] =
                    uint16_t(std::clamp(std::lround(g), 0L, 65535L));
            }
    return part;
}

inline std::string nrrdVector(const Vec3d& v)
{
    std::ostringstream os;
    os.precision(17);
    os << "(" << v.x << "," << v.y << "," << v.z << ")";
    return os.str();
}

/// Writes a uint16 3D NRRD (raw, little-endian, LPS space).
inline void writeNrrdU16(const std::string& path, const ImageGeometry& g, const std::vector<uint16_t>& data)
{
    std::ofstream out(path, std::ios::binary);
    out << "NRRD0004\ntype: uint16\ndimension: 3\nspace: left-posterior-superior\n"
        << "sizes: " << g.size[0] << " " << g.size[1] << " " << g.size[2] << "\n"
        << "space directions: " << nrrdVector({g.spacingMm.x, 0, 0}) << " " << nrrdVector({0, g.spacingMm.y, 0}) << " "
        << nrrdVector({0, 0, g.spacingMm.z}) << "\nkinds: domain domain domain\nendian: little\nencoding: raw\n"
        << "space origin: " << nrrdVector(g.originMm) << "\n\n";
    out.write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size() * sizeof(uint16_t)));
}

/// A 2D uint16 NRRD image (a radiograph, not a volume).
inline void writeNrrd2D(const std::string& path, int w, int h)
{
    std::ofstream out(path, std::ios::binary);
    out << "NRRD0004\ntype: uint16\ndimension: 2\nsizes: " << w << " " << h
        << "\nspacings: 0.5 0.5\nendian: little\nencoding: raw\n\n";
    std::vector<uint16_t> data(std::size_t(w) * h, 20000);
    out.write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size() * sizeof(uint16_t)));
}

/// A 3D RGB colour NRRD (3 components per voxel).
inline void writeNrrdRgb(const std::string& path, int n)
{
    std::ofstream out(path, std::ios::binary);
    out << "NRRD0004\ntype: uint8\ndimension: 4\nspace: left-posterior-superior\nsizes: 3 " << n << " " << n << " " << n
        << "\nspace directions: none (1,0,0) (0,1,0) (0,0,1)\nkinds: RGB-color domain domain domain\n"
        << "endian: little\nencoding: raw\nspace origin: (0,0,0)\n\n";
    std::vector<uint8_t> data(std::size_t(3) * n * n * n, 128);
    out.write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size()));
}

/// The part's grey values as the inspect ingest makes them (every voxel active).
inline openvdb::FloatGrid::Ptr partGrid(const TestPart& part)
{
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setTransform(makeGridTransform(part.geometry.originMm, part.geometry.direction, part.voxelMm()));
    auto acc = grid->getAccessor();
    const auto& s = part.geometry.size;
    for (int k = 0; k < s[2]; ++k)
        for (int j = 0; j < s[1]; ++j)
            for (int i = 0; i < s[0]; ++i)
                acc.setValue(openvdb::Coord(i, j, k),
                             float(part.grey[std::size_t(i) + std::size_t(s[0]) * (std::size_t(j) + std::size_t(s[1]) * std::size_t(k))]));
    return grid;
}

/// The truth as an analysis, from the shapes at the voxel centres (no thresholding, no
/// components): what analysePart should find, for tests of what comes after it.
inline PartAnalysis truthAnalysis(const TestPart& part, const openvdb::FloatGrid& grid)
{
    PartAnalysis a;
    a.threshold = 0.5 * (part.material + part.air);
    a.thresholdSource = "given";
    a.material = openvdb::BoolGrid::create(false);
    a.outsideAir = openvdb::BoolGrid::create(false);
    a.voidLabels = openvdb::Int32Grid::create(0);
    for (auto* g : {static_cast<openvdb::GridBase*>(a.material.get()), static_cast<openvdb::GridBase*>(a.outsideAir.get()),
                    static_cast<openvdb::GridBase*>(a.voidLabels.get())})
        g->setTransform(grid.transform().copy());
    auto m = a.material->getAccessor();
    auto o = a.outsideAir->getAccessor();
    auto l = a.voidLabels->getAccessor();
    const auto& s = part.geometry.size;
    std::vector<int64_t> count(part.voids.size(), 0);
    for (int k = 0; k < s[2]; ++k)
        for (int j = 0; j < s[1]; ++j)
            for (int i = 0; i < s[0]; ++i) {
                const int c = part.classify(Vec3d{double(i), double(j), double(k)});
                const openvdb::Coord ijk(i, j, k);
                // Masks are their active topology; analysePart leaves the values false.
                if (c == 0) o.setValueOn(ijk, false);
                else if (c == 1) m.setValue(ijk, true);
                else {
                    l.setValue(ijk, c - 1);
                    ++count[std::size_t(c - 2)];
                }
            }
    const double v3 = std::pow(part.voxelMm(), 3);
    for (std::size_t k = 0; k < part.voids.size(); ++k) {
        VoidInfo v;
        v.id = int(k) + 1;
        v.kind = part.voids[k].crack ? "crack" : "pore";
        v.voxels = count[k];
        v.volumeMm3 = double(count[k]) * v3;
        v.equivalentDiameterMm = std::cbrt(6.0 * v.volumeMm3 / M_PI);
        v.centroidLps = part.centreMm(part.voids[k]);
        a.voids.push_back(v);
    }
    return a;
}

} // namespace flyover::test
