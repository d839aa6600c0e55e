// mask_to_ct: a plausible CT (int16 HU) of a colon label mask, on the mask's own voxel lattice,
// so that the CT path (`flyover run CT`) can be timed on the same colon as the mask path
// (`flyover run --mask MASK`): the mask-only segment stage should come near the CT path's
// time, which was only known on the phantoms' smaller colons (bench/mask_vs_ct.sh).
//
//   mask_to_ct MASK OUT.nii.gz [--label N] [--pad-mm P] [--seed S] [--noise-hu H]
//              [--wall-mm W] [--fat-mm F] [--margin-mm M] [--no-spine] [--mask-out PADDED.nii.gz]
//
// What is painted, by the distance d (mm, voxel centre to the nearest mask voxel centre, an
// exact Euclidean distance transform with the mask's spacing):
//   mask voxels (the lumen)            AIR_HU     -1000
//   0 < d <= W (colon wall, W = 3)     WALL_HU       40
//   W < d <= W + F (pericolic fat, 5)  FAT_HU      -100
//   the rest of the body               TISSUE_HU     30, with a subcutaneous fat ring
//                                      (FAT_HU, SUBCUTANEOUS_MM inside the outline) and a
//                                      spine-like bone cylinder (BONE_HU 700) posterior,
//                                      never within W + F + 2 mm of the lumen
//   outside the body                   AIR_HU
// then Gaussian noise of H HU (default 15) from a hash of (seed, voxel index), as the
// phantom's: the same output on any thread count. No partial-volume blur: each voxel is one
// tissue, so the CT's air (below the segment stage's -800 HU) is exactly the mask, one-voxel
// contacts between loops included, and both paths see the same colon.
//
// The body outline is an ellipse per slice (index k; the slice plane holds index axes i, j),
// centred on the mask's box over the slices within BODY_WINDOW_MM, scaled to enclose the
// mask's voxels there and grown by M mm (default 40); slices beyond the mask take the
// nearest slice's outline; every voxel within W + F + 5 mm of the mask is in the body
// whatever the ellipse says, so the colon's wall never meets the outside air.
//
// Geometry: with P = 0 (the default) OUT has the mask's exact geometry (size, origin,
// spacing, direction). A mask cropped to the organ touches its field's edge, and the CT path
// takes air touching the scan's edge for air outside the body (ingest) and drops it
// (segment): such a mask gets a warning, and --pad-mm P widens the field by ceil(P / spacing)
// voxels on each side of each axis, on the same lattice (the same spacing and direction, the
// origin moved by whole voxels). --mask-out writes the mask (uint8, 1 = lumen) on OUT's field.
//
// Bad input (a missing or unreadable file, an empty mask, an absent label, a bad option):
// one line on stderr naming the file or option, exit 1, nothing written.
#include "volume/error.h"
#include "volume/image.h"
#include "volume/image_io.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <limits>
#include <set>
#include <sstream>
#include <string>
#include <vector>

using namespace flyover;

namespace {

constexpr double AIR_HU = -1000.0;
constexpr double WALL_HU = 40.0;
constexpr double FAT_HU = -100.0;
constexpr double TISSUE_HU = 30.0;
constexpr double BONE_HU = 700.0;
constexpr double SUBCUTANEOUS_MM = 15.0;   ///< fat ring inside the body outline
constexpr double SPINE_RADIUS_MM = 15.0;
constexpr double SPINE_DEPTH_MM = 30.0;    ///< spine surface to the inner edge of the fat ring
constexpr double BODY_WINDOW_MM = 25.0;    ///< slices either side whose mask shapes a slice's outline
constexpr double TWO_PI = 6.283185307179586476925;
constexpr float FAR_MM2 = std::numeric_limits<float>::max();

struct Options {
    std::string maskPath, outPath, maskOutPath;
    int label = 0;          ///< 0: every non-zero voxel is lumen
    double padMm = 0;
    uint64_t seed = 1;
    double noiseHu = 15;
    double wallMm = 3;
    double fatMm = 5;
    double marginMm = 40;
    bool spine = true;
};

int usage()
{
    std::cerr << "usage: mask_to_ct MASK OUT.nii.gz [--label N] [--pad-mm P] [--seed S] [--noise-hu H] "
                 "[--wall-mm W] [--fat-mm F] [--margin-mm M] [--no-spine] [--mask-out PADDED.nii.gz]\n";
    return 2;
}

double parseNumber(const std::string& name, const std::string& text, double lo, double hi)
{
    std::size_t used = 0;
    double v = 0;
    try {
        v = std::stod(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (text.empty() || used != text.size() || !std::isfinite(v) || v < lo || v > hi) {
        std::ostringstream msg;
        msg << name << ": expected a number in [" << lo << ", " << hi << "], got \"" << text << "\"";
        throw ParameterError(msg.str());
    }
    return v;
}

bool endsWith(const std::string& s, const std::string& tail)
{
    return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

void checkNiftiName(const std::string& option, const std::string& path)
{
    if (!endsWith(path, ".nii.gz") && !endsWith(path, ".nii"))
        throw ParameterError(option + ": \"" + path + "\": expected a .nii.gz or .nii file name");
}

/// splitmix64 finaliser: the counter-based hash behind the noise (thread-count free).
uint64_t splitmix64(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

/// A standard normal sample that depends only on (seed, voxel index) (Box-Muller).
double voxelNoise(uint64_t seedKey, uint64_t voxelIndex)
{
    const uint64_t h = splitmix64(seedKey + splitmix64(voxelIndex));
    const double u1 = (double(h >> 32) + 0.5) * 0x1.0p-32;    // (0, 1)
    const double u2 = double(h & 0xFFFFFFFFull) * 0x1.0p-32;  // [0, 1)
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(TWO_PI * u2);
}

/// The lumen voxels of the mask on the output field, and that field's geometry.
struct PaddedMask {
    ImageGeometry geometry;
    std::array<int64_t, 3> pad{0, 0, 0};
    std::vector<uint8_t> inside;
    int64_t count = 0;
    int edgeFaces = 0;  ///< faces of the mask's own field that lumen voxels touch
};

PaddedMask readMask(const Options& opt)
{
    std::unique_ptr<ImageSource> source = openImage(opt.maskPath);
    const ImageGeometry& g = source->geometry();
    if (!source->isRegular())
        throw InputError(opt.maskPath + ": slices not on a regular lattice (gaps or tilt): not a mask this tool reads");
    PaddedMask out;
    out.geometry = g;
    Vec3d shift{0, 0, 0};
    for (int a = 0; a < 3; ++a) {
        out.pad[a] = int64_t(std::ceil(opt.padMm / g.spacingMm[a] - 1e-9));
        out.geometry.size[a] = g.size[a] + 2 * out.pad[a];
        shift[a] = -double(out.pad[a]);
    }
    out.geometry.originMm = g.worldFromIndex(shift);
    const ImageGeometry& og = out.geometry;
    out.inside.assign(std::size_t(og.voxelCount()), 0);

    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    const std::size_t perSlice = std::size_t(nx * ny);
    constexpr int64_t SLAB = 16;
    std::vector<float> slab(perSlice * SLAB);
    std::set<double> values;  // the first few distinct values, for the message of an absent label
    bool faces[6] = {false, false, false, false, false, false};
    for (int64_t k0 = 0; k0 < nz; k0 += SLAB) {
        const int64_t k1 = std::min(nz, k0 + SLAB);
        source->readSlices(k0, k1, slab.data());
        for (int64_t k = k0; k < k1; ++k)
            for (int64_t j = 0; j < ny; ++j) {
                const float* row = slab.data() + perSlice * std::size_t(k - k0) + std::size_t(j * nx);
                uint8_t* dst = out.inside.data() +
                               std::size_t(out.pad[0] + og.size[0] * (j + out.pad[1] + og.size[1] * (k + out.pad[2])));
                for (int64_t i = 0; i < nx; ++i) {
                    const float v = row[i];
                    if (values.size() < 16) values.insert(double(v));
                    const bool in = opt.label == 0 ? v != 0.0f : v == float(opt.label);
                    if (!in) continue;
                    dst[i] = 1;
                    ++out.count;
                    faces[0] |= i == 0;
                    faces[1] |= i == nx - 1;
                    faces[2] |= j == 0;
                    faces[3] |= j == ny - 1;
                    faces[4] |= k == 0;
                    faces[5] |= k == nz - 1;
                }
            }
    }
    for (bool f : faces) out.edgeFaces += f ? 1 : 0;
    if (out.count == 0) {
        if (opt.label == 0) throw InputError(opt.maskPath + ": empty mask (no non-zero voxel)");
        std::ostringstream msg;
        msg << opt.maskPath << ": label " << opt.label << " is absent (values present:";
        for (double v : values) msg << " " << v;
        msg << (values.size() >= 16 ? " ...)" : ")");
        throw InputError(msg.str());
    }
    return out;
}

/// Exact squared Euclidean distance transform along one line (Felzenszwalb & Huttenlocher):
/// d[q] = min_p ((q - p) * step)^2 + f[p]; FAR_MM2 marks no site.
void distanceLine(const float* f, float* d, int64_t n, double step, std::vector<int64_t>& v, std::vector<double>& z)
{
    v.resize(std::size_t(n));
    z.resize(std::size_t(n) + 1);
    int64_t k = -1;
    for (int64_t q = 0; q < n; ++q) {
        if (f[q] >= FAR_MM2) continue;
        const double xq = double(q) * step, fq = double(f[q]) + xq * xq;
        double s = -std::numeric_limits<double>::infinity();
        while (k >= 0) {
            const double xv = double(v[k]) * step;
            s = (fq - (double(f[v[k]]) + xv * xv)) / (2.0 * (xq - xv));
            if (s > z[k]) break;
            --k;
        }
        ++k;
        v[k] = q;
        z[k] = k == 0 ? -std::numeric_limits<double>::infinity() : s;
        z[k + 1] = std::numeric_limits<double>::infinity();
    }
    if (k < 0) {
        std::fill(d, d + n, FAR_MM2);
        return;
    }
    int64_t j = 0;
    for (int64_t q = 0; q < n; ++q) {
        const double x = double(q) * step;
        while (z[j + 1] < x) ++j;
        const double dx = x - double(v[j]) * step;
        d[q] = float(std::min(dx * dx + double(f[v[j]]), double(FAR_MM2) * 0.5));
    }
}

/// Squared distance (mm^2) of every voxel centre to the nearest lumen voxel centre.
std::vector<float> squaredDistanceMm2(const PaddedMask& m)
{
    const auto& g = m.geometry;
    const int64_t n[3] = {g.size[0], g.size[1], g.size[2]};
    const int64_t stride[3] = {1, n[0], n[0] * n[1]};
    std::vector<float> d2(m.inside.size());
    for (std::size_t v = 0; v < d2.size(); ++v) d2[v] = m.inside[v] ? 0.0f : FAR_MM2;
    // One axis at a time; lines along `axis` in blocks of BLOCK neighbours along the fastest
    // other axis, so the strided passes read whole cache lines.
    constexpr int64_t BLOCK = 16;
    for (int axis = 0; axis < 3; ++axis) {
        const int a = axis == 0 ? 1 : 0;          // the blocked axis
        const int b = axis == 2 ? 1 : 2;          // the remaining axis
        const int64_t len = n[axis], along = n[a], blocks = (along + BLOCK - 1) / BLOCK;
        const int64_t strideAxis = stride[axis], strideA = stride[a], strideB = stride[b];
        const double step = g.spacingMm[axis];
        float* data = d2.data();
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, blocks * n[b]), [=](const tbb::blocked_range<int64_t>& r) {
            std::vector<float> in(static_cast<std::size_t>(len * BLOCK)), out(static_cast<std::size_t>(len));
            std::vector<int64_t> v;
            std::vector<double> z;
            for (int64_t t = r.begin(); t != r.end(); ++t) {
                const int64_t a0 = (t % blocks) * BLOCK, a1 = std::min(along, a0 + BLOCK);
                const int64_t base = (t / blocks) * strideB;
                for (int64_t q = 0; q < len; ++q)
                    for (int64_t l = a0; l < a1; ++l)
                        in[std::size_t((l - a0) * len + q)] = data[base + q * strideAxis + l * strideA];
                for (int64_t l = a0; l < a1; ++l) {
                    distanceLine(in.data() + (l - a0) * len, out.data(), len, step, v, z);
                    for (int64_t q = 0; q < len; ++q) data[base + q * strideAxis + l * strideA] = out[std::size_t(q)];
                }
            }
        });
    }
    return d2;
}

/// The body outline of one slice: an ellipse in the slice's (i, j) plane, in mm from voxel
/// (0, 0) along the index axes.
struct Outline {
    double cx = 0, cy = 0, ax = 1, ay = 1;
};

std::vector<Outline> bodyOutlines(const PaddedMask& m, double marginMm)
{
    const auto& g = m.geometry;
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    const double sx = g.spacingMm.x, sy = g.spacingMm.y;
    struct Box {
        double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
        bool empty() const { return x0 > x1; }
    };
    std::vector<Box> own(static_cast<std::size_t>(nz));
    tbb::parallel_for(int64_t(0), nz, [&](int64_t k) {
        Box& b = own[std::size_t(k)];
        for (int64_t j = 0; j < ny; ++j) {
            const uint8_t* row = m.inside.data() + std::size_t(nx * (j + ny * k));
            for (int64_t i = 0; i < nx; ++i)
                if (row[i]) {
                    b.x0 = std::min(b.x0, double(i) * sx);
                    b.x1 = std::max(b.x1, double(i) * sx);
                    b.y0 = std::min(b.y0, double(j) * sy);
                    b.y1 = std::max(b.y1, double(j) * sy);
                }
        }
    });
    // Slices without lumen take the nearest slice's box.
    int64_t first = -1, last = -1;
    for (int64_t k = 0; k < nz; ++k)
        if (!own[std::size_t(k)].empty()) {
            if (first < 0) first = k;
            last = k;
        }
    Box carry = own[std::size_t(first)];
    for (int64_t k = 0; k < nz; ++k) {
        if (own[std::size_t(k)].empty()) {
            int64_t next = k;
            while (next <= last && own[std::size_t(next)].empty()) ++next;
            own[std::size_t(k)] = (k < first || next > last) ? carry : own[std::size_t(next)];
        }
        carry = own[std::size_t(k)];
    }
    const int64_t window = int64_t(BODY_WINDOW_MM / g.spacingMm.z);
    std::vector<Box> joined(static_cast<std::size_t>(nz));
    for (int64_t k = 0; k < nz; ++k) {
        Box& b = joined[std::size_t(k)];
        for (int64_t q = std::max<int64_t>(0, k - window); q <= std::min(nz - 1, k + window); ++q) {
            const Box& o = own[std::size_t(q)];
            b.x0 = std::min(b.x0, o.x0);
            b.x1 = std::max(b.x1, o.x1);
            b.y0 = std::min(b.y0, o.y0);
            b.y1 = std::max(b.y1, o.y1);
        }
    }
    // Normalised radius of each slice's lumen voxels against its joined box's half sizes.
    std::vector<double> reach(std::size_t(nz), 1.0);
    tbb::parallel_for(int64_t(0), nz, [&](int64_t k) {
        const Box& b = joined[std::size_t(k)];
        const double cx = 0.5 * (b.x0 + b.x1), cy = 0.5 * (b.y0 + b.y1);
        const double hx = 0.5 * (b.x1 - b.x0) + sx, hy = 0.5 * (b.y1 - b.y0) + sy;
        double r2 = 1.0;
        for (int64_t j = 0; j < ny; ++j) {
            const uint8_t* row = m.inside.data() + std::size_t(nx * (j + ny * k));
            const double dy = (double(j) * sy - cy) / hy;
            for (int64_t i = 0; i < nx; ++i)
                if (row[i]) {
                    const double dx = (double(i) * sx - cx) / hx;
                    r2 = std::max(r2, dx * dx + dy * dy);
                }
        }
        reach[std::size_t(k)] = std::sqrt(r2);
    });
    std::vector<Outline> out(static_cast<std::size_t>(nz));
    for (int64_t k = 0; k < nz; ++k) {
        double r = 1.0;
        for (int64_t q = std::max<int64_t>(0, k - window); q <= std::min(nz - 1, k + window); ++q)
            r = std::max(r, reach[std::size_t(q)]);
        const Box& b = joined[std::size_t(k)];
        Outline& o = out[std::size_t(k)];
        o.cx = 0.5 * (b.x0 + b.x1);
        o.cy = 0.5 * (b.y0 + b.y1);
        o.ax = r * (0.5 * (b.x1 - b.x0) + sx) + marginMm;
        o.ay = r * (0.5 * (b.y1 - b.y0) + sy) + marginMm;
    }
    return out;
}

/// |value| of a normalised ellipse equation: < 1 inside.
double ellipseLevel(double dx, double dy, double ax, double ay)
{
    return (dx * dx) / (ax * ax) + (dy * dy) / (ay * ay);
}

Image3<int16_t> paintCt(const PaddedMask& m, const std::vector<float>& d2, const std::vector<Outline>& outlines,
                        const Options& opt, double& bodyFraction)
{
    const auto& g = m.geometry;
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    const double sx = g.spacingMm.x, sy = g.spacingMm.y;
    Image3<int16_t> ct;
    ct.geometry = g;
    ct.voxels.assign(m.inside.size(), 0);
    // Posterior (world +y in LPS) in the slice plane: the in-plane index axis nearest it.
    const int backAxis = std::abs(g.direction[1][0]) >= std::abs(g.direction[1][1]) ? 0 : 1;
    const double backSign = g.direction[1][backAxis] >= 0 ? 1.0 : -1.0;
    const double wall2 = opt.wallMm * opt.wallMm;
    const double fat2 = (opt.wallMm + opt.fatMm) * (opt.wallMm + opt.fatMm);
    const double keepBody2 = (opt.wallMm + opt.fatMm + 5.0) * (opt.wallMm + opt.fatMm + 5.0);
    const double clearBone2 = (opt.wallMm + opt.fatMm + 2.0) * (opt.wallMm + opt.fatMm + 2.0);
    const uint64_t seedKey = splitmix64(opt.seed ^ 0x3A5C0C7ull);
    std::vector<int64_t> bodyPerSlice(std::size_t(nz), 0);
    tbb::parallel_for(int64_t(0), nz, [&](int64_t k) {
        const Outline& o = outlines[std::size_t(k)];
        const double innerX = std::max(1.0, o.ax - SUBCUTANEOUS_MM), innerY = std::max(1.0, o.ay - SUBCUTANEOUS_MM);
        double spineX = o.cx, spineY = o.cy;
        const double backReach = (backAxis == 0 ? innerX : innerY) - SPINE_DEPTH_MM - SPINE_RADIUS_MM;
        (backAxis == 0 ? spineX : spineY) += backSign * std::max(0.0, backReach);
        int64_t body = 0;
        for (int64_t j = 0; j < ny; ++j) {
            const double y = double(j) * sy;
            for (int64_t i = 0; i < nx; ++i) {
                const std::size_t v = std::size_t(i + nx * (j + ny * k));
                const double x = double(i) * sx;
                const double dd = d2[v];
                double hu;
                if (m.inside[v]) hu = AIR_HU;
                else if (dd <= wall2) hu = WALL_HU;
                else if (dd <= fat2) hu = FAT_HU;
                else if (ellipseLevel(x - o.cx, y - o.cy, o.ax, o.ay) > 1.0 && dd > keepBody2) hu = AIR_HU;
                else if (ellipseLevel(x - o.cx, y - o.cy, innerX, innerY) > 1.0) hu = FAT_HU;
                else if (opt.spine && dd > clearBone2 &&
                         (x - spineX) * (x - spineX) + (y - spineY) * (y - spineY) <= SPINE_RADIUS_MM * SPINE_RADIUS_MM)
                    hu = BONE_HU;
                else hu = TISSUE_HU;
                body += (m.inside[v] || hu != AIR_HU) ? 1 : 0;
                hu += opt.noiseHu * voxelNoise(seedKey, uint64_t(v));
                ct.voxels[v] = int16_t(std::clamp(std::round(hu), -32768.0, 32767.0));
            }
        }
        bodyPerSlice[std::size_t(k)] = body;
    });
    int64_t body = 0;
    for (int64_t b : bodyPerSlice) body += b;
    bodyFraction = double(body) / double(std::max<int64_t>(1, g.voxelCount()));
    return ct;
}

} // namespace

int main(int argc, char** argv)
{
    Options opt;
    std::vector<std::string> positional;
    try {
        for (int i = 1; i < argc; ++i) {
            const std::string a = argv[i];
            if (a == "--no-spine") {
                opt.spine = false;
                continue;
            }
            if (a.rfind("--", 0) != 0) {
                positional.push_back(a);
                continue;
            }
            if (i + 1 >= argc) throw ParameterError(a + ": expected a value");
            const std::string value = argv[++i];
            if (a == "--label") opt.label = int(parseNumber(a, value, 1, 1e6));
            else if (a == "--pad-mm") opt.padMm = parseNumber(a, value, 0, 500);
            else if (a == "--seed") opt.seed = uint64_t(parseNumber(a, value, 0, 1e15));
            else if (a == "--noise-hu") opt.noiseHu = parseNumber(a, value, 0, 200);
            else if (a == "--wall-mm") opt.wallMm = parseNumber(a, value, 0.1, 20);
            else if (a == "--fat-mm") opt.fatMm = parseNumber(a, value, 0, 50);
            else if (a == "--margin-mm") opt.marginMm = parseNumber(a, value, 0, 500);
            else if (a == "--mask-out") opt.maskOutPath = value;
            else throw ParameterError(a + ": unknown option");
            if (a == "--label" && value.find_first_not_of("0123456789") != std::string::npos)
                throw ParameterError("--label: expected a whole number >= 1, got \"" + value + "\"");
        }
        if (positional.size() != 2) return usage();
        opt.maskPath = positional[0];
        opt.outPath = positional[1];
        checkNiftiName("OUT", opt.outPath);
        if (!opt.maskOutPath.empty()) checkNiftiName("--mask-out", opt.maskOutPath);

        const auto t0 = std::chrono::steady_clock::now();
        PaddedMask mask = readMask(opt);
        if (mask.edgeFaces > 0 && opt.padMm == 0)
            std::cerr << "mask_to_ct: warning: " << opt.maskPath << ": the lumen touches " << mask.edgeFaces
                      << " of the field's 6 faces; the CT path takes air at the scan's edge for outside air "
                         "(use --pad-mm)\n";
        const std::vector<float> d2 = squaredDistanceMm2(mask);
        const std::vector<Outline> outlines = bodyOutlines(mask, opt.marginMm);
        double bodyFraction = 0;
        const Image3<int16_t> ct = paintCt(mask, d2, outlines, opt, bodyFraction);
        writeImage(ct, opt.outPath);
        if (!opt.maskOutPath.empty()) {
            Image3<uint8_t> out;
            out.geometry = mask.geometry;
            out.voxels = std::move(mask.inside);
            writeImage(out, opt.maskOutPath);
        }
        const auto& g = ct.geometry;
        const double voxelMl = g.spacingMm.x * g.spacingMm.y * g.spacingMm.z * 1e-3;
        std::printf("mask_to_ct: %s -> %s: %lld x %lld x %lld voxels (pad %lld, %lld, %lld), lumen %.1f mL "
                    "(%lld voxels), body %.1f%% of the field, %.1f s\n",
                    opt.maskPath.c_str(), opt.outPath.c_str(), (long long)g.size[0], (long long)g.size[1],
                    (long long)g.size[2], (long long)mask.pad[0], (long long)mask.pad[1], (long long)mask.pad[2],
                    double(mask.count) * voxelMl, (long long)mask.count, 100.0 * bodyFraction,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    } catch (const std::exception& e) {
        std::cerr << "mask_to_ct: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
