/// @file part_phantom.cpp
/// @brief The industrial part phantom (see part_phantom.h): analytic shapes, exact partial
///        volume near surfaces, separable Gaussian blur over a ring of slices, noise per row.
#include "inspect/part_phantom.h"
#include "volume/vec3.h"

#include "volume/error.h"
#include "inspect/voids.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <unordered_set>

namespace flyover {

namespace {

/// Half the diagonal of a voxel: a surface farther than this from the centre misses the cube.
constexpr double HALF_DIAGONAL = 0.8660254037844386;
constexpr int SUPERSAMPLE = 4;    // 4 x 4 x 4 point samples per boundary voxel
constexpr double GAP_VOXELS = 5;  // material kept between a void and any surface or void (>= 4)

uint64_t splitmix64(uint64_t& state)
{
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/// Deterministic uniform [0,1) (53 bits), independent of the standard library's distributions.
struct Rng {
    uint64_t state;
    explicit Rng(uint64_t seed) : state(seed) {}
    double uniform() { return static_cast<double>(splitmix64(state) >> 11) * (1.0 / 9007199254740992.0); }
    double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
    double normal()
    {
        // Box-Muller; u1 in (0,1]
        const double u1 = 1.0 - uniform(), u2 = uniform();
        return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * PI * u2);
    }
};

/// The part in index coordinates (see part_phantom.h).
struct PartShape {
    double c = 0, rBody = 0, rFlange = 0, rBore = 0, z0 = 0, z1 = 0, zFlange = 0;

    static double cappedCylinder(double r, double z, double radius, double za, double zb)
    {
        const double dr = r - radius, dz = std::max(za - z, z - zb);
        if (dr <= 0 && dz <= 0) return std::max(dr, dz);
        return std::hypot(std::max(dr, 0.0), std::max(dz, 0.0));
    }
    /// Signed distance bound (negative in the material; its magnitude never exceeds the true
    /// distance, so |sd| > HALF_DIAGONAL safely means "the voxel is all on one side").
    double sd(const Vec3d& p) const
    {
        const double x = p.x - c, y = p.y - c, r = std::hypot(x, y);
        const double solid = std::min(cappedCylinder(r, p.z, rBody, z0, z1),
                                      cappedCylinder(r, p.z, rFlange, z0, zFlange));
        return std::max(solid, rBore - r);
    }
};

/// A void: an ellipsoid (semi-axes a, b, c) or an elliptic disc (semi-axes a, b, half
/// thickness h), in a frame whose columns (u, v, w) are unit vectors in index space.
struct Shape {
    bool disc = false;
    Vec3d centre, axes;
    std::array<Vec3d, 3> frame;
    std::array<int64_t, 3> lo{}, hi{};  ///< inclusive index bounding box

    Vec3d local(const Vec3d& p) const
    {
        const Vec3d d = p - centre;
        return {dot(d, frame[0]), dot(d, frame[1]), dot(d, frame[2])};
    }
    bool inside(const Vec3d& p) const
    {
        const Vec3d l = local(p);
        if (disc) {
            const double u = l.x / axes.x, v = l.y / axes.y;
            return u * u + v * v <= 1.0 && std::abs(l.z) <= axes.z;
        }
        const double u = l.x / axes.x, v = l.y / axes.y, w = l.z / axes.z;
        return u * u + v * v + w * w <= 1.0;
    }
    /// -1: the voxel cube around p is surely outside, +1 surely inside, 0: it may be cut.
    /// Scaling by 1/axes is Lipschitz with 1/min(axes), so min(axes) * |q - 1| bounds the distance.
    int classify(const Vec3d& p) const
    {
        const Vec3d l = local(p);
        if (disc) {
            const double rho = std::hypot(l.x / axes.x, l.y / axes.y), m = std::min(axes.x, axes.y);
            if (std::abs(l.z) - axes.z > HALF_DIAGONAL || m * (rho - 1.0) > HALF_DIAGONAL) return -1;
            if (axes.z - std::abs(l.z) > HALF_DIAGONAL && m * (1.0 - rho) > HALF_DIAGONAL) return 1;
            return 0;
        }
        const double q = std::sqrt((l.x / axes.x) * (l.x / axes.x) + (l.y / axes.y) * (l.y / axes.y) +
                                   (l.z / axes.z) * (l.z / axes.z));
        const double m = std::min({axes.x, axes.y, axes.z});
        if (m * (q - 1.0) > HALF_DIAGONAL) return -1;
        if (m * (1.0 - q) > HALF_DIAGONAL) return 1;
        return 0;
    }
    double boundingRadius() const { return disc ? std::hypot(std::max(axes.x, axes.y), axes.z) : std::max({axes.x, axes.y, axes.z}); }
    /// Points on the shape's surface (for the clearance test).
    std::vector<Vec3d> surfaceSamples() const
    {
        std::vector<Vec3d> pts;
        const int nPhi = 32, nTheta = 16;
        for (int t = 0; t <= nTheta; ++t) {
            for (int f = 0; f < nPhi; ++f) {
                const double phi = 2 * PI * f / nPhi;
                Vec3d l;
                if (disc) {
                    const double rho = static_cast<double>(t) / nTheta;
                    for (double side : {-1.0, 1.0}) {
                        l = {axes.x * rho * std::cos(phi), axes.y * rho * std::sin(phi), side * axes.z};
                        pts.push_back(centre + frame[0] * l.x + frame[1] * l.y + frame[2] * l.z);
                    }
                    continue;
                }
                const double theta = PI * t / nTheta;
                l = {axes.x * std::sin(theta) * std::cos(phi), axes.y * std::sin(theta) * std::sin(phi),
                     axes.z * std::cos(theta)};
                pts.push_back(centre + frame[0] * l.x + frame[1] * l.y + frame[2] * l.z);
            }
        }
        return pts;
    }
    void computeBounds(int64_t n)
    {
        for (int e = 0; e < 3; ++e) {
            // half extent of the box (a, b, c|h) in the frame along world axis e
            const double half = std::abs(frame[0][e]) * axes.x + std::abs(frame[1][e]) * axes.y +
                                std::abs(frame[2][e]) * axes.z + 1.0;
            lo[e] = std::max<int64_t>(0, static_cast<int64_t>(std::floor(centre[e] - half)));
            hi[e] = std::min<int64_t>(n - 1, static_cast<int64_t>(std::ceil(centre[e] + half)));
        }
    }
};

/// Orthonormal frame whose first axis is `u`.
std::array<Vec3d, 3> frameFrom(const Vec3d& uIn, const Vec3d& hint)
{
    const Vec3d u = normalize(uIn);
    Vec3d v = hint - u * dot(hint, u);
    if (length(v) < 1e-6) v = std::abs(u.x) < 0.9 ? Vec3d{1, 0, 0} - u * u.x : Vec3d{0, 1, 0} - u * u.y;
    v = normalize(v);
    return {u, v, cross(u, v)};
}

Vec3d randomUnit(Rng& rng)
{
    const double z = rng.uniform(-1, 1), phi = rng.uniform(0, 2 * PI), s = std::sqrt(1 - z * z);
    return {s * std::cos(phi), s * std::sin(phi), z};
}

struct VoidHit {
    int shape;
    int64_t i;
    double fraction;
};

struct VoidAccumulator {
    double volume = 0;       // sum of air fractions (voxels)
    Vec3d weighted;          // sum of fraction x index
    int64_t voxels = 0;
    std::vector<std::array<int32_t, 3>> counted;  // voxels with fraction >= 0.5
};

std::vector<double> gaussianKernel(double sigma)
{
    if (!(sigma > 0)) return {1.0};
    const int radius = static_cast<int>(std::ceil(3.0 * sigma));
    std::vector<double> k(2 * radius + 1);
    double sum = 0;
    for (int t = -radius; t <= radius; ++t) sum += k[t + radius] = std::exp(-0.5 * t * t / (sigma * sigma));
    for (double& w : k) w /= sum;  // normalised: the blur keeps every volume
    return k;
}

void checkParams(const PartPhantomParams& p)
{
    if (p.size < 112 || p.size > 2048)
        throw ParameterError("--size: the part phantom takes 112..2048 voxels (got " + std::to_string(p.size) + ")");
    if (!(p.voxelMm > 0) || !std::isfinite(p.voxelMm)) throw ParameterError("voxel size: must be > 0 mm");
    if (!(p.airGrey >= 0) || !(p.materialGrey <= 65535) || !(p.materialGrey > p.airGrey))
        throw ParameterError("grey values: need 0 <= air < material <= 65535 (got air " +
                             std::to_string(p.airGrey) + ", material " + std::to_string(p.materialGrey) + ")");
    if (!std::isfinite(p.noiseSigma)) throw ParameterError("noise: must be finite");
    if (!(p.blurVoxels >= 0 && p.blurVoxels <= 2)) throw ParameterError("blur: must be 0..2 voxels");
    if (p.pores < 0 || p.pores > 100000) throw ParameterError("--pores: must be 0..100000");
}

/// The defaults resolved: noise 4% of the contrast, 12 x (size/128)^2 pores.
PartPhantomParams resolvedParams(const PartPhantomParams& paramsIn)
{
    PartPhantomParams params = paramsIn;
    const int64_t n = params.size;
    if (params.noiseSigma < 0) params.noiseSigma = 0.04 * (params.materialGrey - params.airGrey);
    if (params.pores == 0) params.pores = static_cast<int>(std::lround(12.0 * (n / 128.0) * (n / 128.0)));
    return params;
}

/// The part of an n^3 grid centred on c (see part_phantom.h).
PartShape partShape(int64_t n, double c)
{
    PartShape part;
    part.c = c;
    part.rBody = 0.34 * n;
    part.rFlange = 0.46 * n;
    part.rBore = 0.08 * n;
    part.z0 = 0.10 * n;
    part.z1 = 0.90 * n;
    part.zFlange = 0.22 * n;
    return part;
}

constexpr int MAX_TRIES = 20000;  // random placements tried per void

/// The voids placed so far, in generation order, and their kinds.
struct PlacedVoids {
    std::vector<Shape> shapes;
    std::vector<std::string> kinds;

    void add(const Shape& s, const char* kind)
    {
        shapes.push_back(s);
        kinds.push_back(kind);
    }
    /// Whether s keeps GAP_VOXELS to every void placed (bounding spheres).
    bool clearOf(const Shape& s) const
    {
        for (const Shape& o : shapes)
            if (distance(o.centre, s.centre) < o.boundingRadius() + s.boundingRadius() + GAP_VOXELS) return false;
        return true;
    }
};

/// Whether s keeps `gap` voxels of material to the part's surfaces (at its surface samples).
bool clearOfSurfaces(const PartShape& part, const Shape& s, double gap)
{
    for (const Vec3d& q : s.surfaceSamples())
        if (!(part.sd(q) <= -gap)) return false;
    return true;
}

/// The internal crack: roughly tangential to the wall, in the middle of it.
void placeInternalCrack(Rng& rng, const PartShape& part, int64_t n, PlacedVoids& voids)
{
    const double c = part.c;
    bool placed = false;
    for (int t = 0; t < MAX_TRIES && !placed; ++t) {
        const double phi = rng.uniform(0, 2 * PI), tilt = rng.uniform(-0.35, 0.35);
        const double rMid = 0.5 * (part.rBore + part.rBody);
        Shape s;
        s.disc = true;
        s.axes = {14, 10, 0.9};
        const Vec3d radial{std::cos(phi), std::sin(phi), 0};
        const Vec3d normal = normalize(radial * std::cos(tilt) + Vec3d{0, 0, 1} * std::sin(tilt));
        const std::array<Vec3d, 3> f = frameFrom(Vec3d{0, 0, 1} - normal * normal.z, Vec3d{-radial.y, radial.x, 0});
        s.frame = {f[0], f[1], normal};
        // |n|_1 <= thickness keeps the digital disc face-connected
        if (std::abs(normal.x) + std::abs(normal.y) + std::abs(normal.z) > 1.7) continue;
        s.centre = {c + rMid * radial.x, c + rMid * radial.y, rng.uniform(part.zFlange + 10, part.z1 - 10)};
        if (!clearOfSurfaces(part, s, GAP_VOXELS)) continue;
        voids.add(s, "crack");
        placed = true;
    }
    if (!placed)
        throw ParameterError("--size: the internal crack does not fit in a part of " + std::to_string(n) + " voxels");
}

/// The crack open to the surface: half inside the outer wall, in a plane through the axis.
void placeOpenCrack(Rng& rng, const PartShape& part, PlacedVoids& voids)
{
    const double c = part.c;
    bool placed = false;
    for (int t = 0; t < MAX_TRIES && !placed; ++t) {
        const double phi = rng.uniform(0, 2 * PI), tilt = rng.uniform(-0.3, 0.3);
        const Vec3d radial{std::cos(phi), std::sin(phi), 0}, tangent{-radial.y, radial.x, 0};
        Shape s;
        s.disc = true;
        s.axes = {12, 8, 1.1};
        const Vec3d normal = normalize(tangent * std::cos(tilt) + Vec3d{0, 0, 1} * std::sin(tilt));
        const std::array<Vec3d, 3> f = frameFrom(radial, Vec3d{0, 0, 1});
        s.frame = {f[0], f[1], normal};
        s.frame[1] = normalize(cross(normal, radial));
        s.centre = {c + part.rBody * radial.x, c + part.rBody * radial.y,
                    rng.uniform(part.zFlange + 16, part.z1 - 16)};
        if (!voids.clearOf(s)) continue;
        voids.add(s, "open_crack");
        placed = true;
    }
    if (!placed) throw ParameterError("--size: the open crack does not fit");
}

struct PoreSpec { bool elongated; double longD, shortD; };

/// The pores' diameters, largest first; diameters cover 3..16 voxels, then random.
std::vector<PoreSpec> poreSpecs(int pores, Rng& rng)
{
    std::vector<PoreSpec> specs;
    const double sphereD[] = {16, 3, 10, 4, 6, 12, 5, 8};
    const double longD[] = {16, 8, 12, 10, 14, 6};
    for (int i = 0; i < pores; ++i) {
        PoreSpec p;
        p.elongated = (i % 2) == 1;
        const int m = i / 2;
        if (!p.elongated) {
            p.longD = p.shortD = m < 8 ? sphereD[m] : rng.uniform(3, 16);
        } else {
            p.longD = m < 6 ? longD[m] : rng.uniform(6, 16);
            p.shortD = std::max(3.0, p.longD / rng.uniform(1.8, 3.0));
        }
        specs.push_back(p);
    }
    std::stable_sort(specs.begin(), specs.end(),
                     [](const PoreSpec& a, const PoreSpec& b) { return a.longD > b.longD; });
    return specs;
}

/// The pores, largest first, each in the material clear of the surfaces and of the other voids.
void placePores(Rng& rng, const PartShape& part, int pores, int64_t n, PlacedVoids& voids)
{
    const double c = part.c;
    for (const PoreSpec& p : poreSpecs(pores, rng)) {
        bool placed = false;
        for (int t = 0; t < MAX_TRIES && !placed; ++t) {
            Shape s;
            s.axes = {0.5 * p.longD, 0.5 * p.shortD, 0.5 * p.shortD};
            s.frame = frameFrom(randomUnit(rng), randomUnit(rng));
            const double r = std::sqrt(rng.uniform(part.rBore * part.rBore, part.rFlange * part.rFlange));
            const double phi = rng.uniform(0, 2 * PI);
            s.centre = {c + r * std::cos(phi), c + r * std::sin(phi), rng.uniform(part.z0, part.z1)};
            if (part.sd(s.centre) > -(s.boundingRadius() * 0.5 + GAP_VOXELS)) continue;
            if (!voids.clearOf(s) || !clearOfSurfaces(part, s, GAP_VOXELS)) continue;
            voids.add(s, "pore");
            placed = true;
        }
        if (!placed)
            throw ParameterError("--pores: only " + std::to_string(voids.shapes.size() - 2) + " of " +
                                 std::to_string(pores) + " pores fit in a part of " + std::to_string(n) + " voxels");
    }
}

/// Of the SUPERSAMPLE^3 point samples of voxel (i, j, k), which the part's surface or a
/// candidate void may cut: the number in the material; counts[t]: the number in void cands[t].
int materialSamples(const PartShape& part, const std::vector<Shape>& shapes, const std::vector<int>& cands,
                       int64_t i, int64_t j, int64_t k, std::array<int, 4>& counts)
{
    int material = 0;
    for (int a = 0; a < SUPERSAMPLE; ++a)
        for (int b = 0; b < SUPERSAMPLE; ++b)
            for (int e = 0; e < SUPERSAMPLE; ++e) {
                const Vec3d q{i + (a + 0.5) / SUPERSAMPLE - 0.5, j + (b + 0.5) / SUPERSAMPLE - 0.5,
                              k + (e + 0.5) / SUPERSAMPLE - 0.5};
                if (part.sd(q) >= 0) continue;
                bool inVoid = false;
                for (std::size_t t = 0; t < cands.size() && t < counts.size(); ++t)
                    if (shapes[cands[t]].inside(q)) { ++counts[t]; inVoid = true; break; }
                if (!inVoid) ++material;
            }
    return material;
}

/// Row j of slice k: each voxel's material fraction into f, its void fractions into hits;
/// returns the row's material volume (voxels). sliceShapes: the voids meeting slice k.
double rowFractions(const PartShape& part, const std::vector<Shape>& shapes, const std::vector<int>& sliceShapes,
                    int64_t n, int64_t j, int64_t k, float* f, std::vector<VoidHit>& hits)
{
    hits.clear();
    std::vector<int> rowShapes, cands;
    for (int s : sliceShapes)
        if (j >= shapes[s].lo[1] && j <= shapes[s].hi[1]) rowShapes.push_back(s);
    double rowSum = 0;
    for (int64_t i = 0; i < n; ++i) {
        const Vec3d p{double(i), double(j), double(k)};
        const double sd = part.sd(p);
        if (sd > HALF_DIAGONAL) { f[i] = 0.0f; continue; }
        cands.clear();
        int insideShape = -1;
        for (int s : rowShapes) {
            if (i < shapes[s].lo[0] || i > shapes[s].hi[0]) continue;
            const int cls = shapes[s].classify(p);
            if (cls == 1) insideShape = s;
            if (cls >= 0) cands.push_back(s);
        }
        if (sd < -HALF_DIAGONAL && cands.empty()) { f[i] = 1.0f; rowSum += 1.0; continue; }
        if (sd < -HALF_DIAGONAL && insideShape >= 0 && cands.size() == 1) {
            f[i] = 0.0f;
            hits.push_back({insideShape, i, 1.0});
            continue;
        }
        std::array<int, 4> counts{0, 0, 0, 0};  // at most a few candidates per voxel
        const int material = materialSamples(part, shapes, cands, i, j, k, counts);
        const double total = SUPERSAMPLE * SUPERSAMPLE * SUPERSAMPLE;
        f[i] = static_cast<float>(material / total);
        rowSum += material / total;
        for (std::size_t t = 0; t < cands.size() && t < counts.size(); ++t)
            if (counts[t] > 0) hits.push_back({cands[t], i, counts[t] / total});
    }
    return rowSum;
}

/// The slices' state: the material fractions of the slice being computed, a ring of them
/// blurred along i and j (one slice per kernel tap, blurred along k when a slice is emitted),
/// and the truth accumulated so far.
class PartSlicer {
public:
    PartSlicer(const PartShape& part, const std::vector<Shape>& shapes, const PartPhantomParams& params)
        : mPart(part), mShapes(shapes), mParams(params), mN(params.size),
          mKernel(gaussianKernel(params.blurVoxels)), mRadius(static_cast<int>(mKernel.size() / 2)),
          mArea(static_cast<std::size_t>(mN * mN)), mRing(mKernel.size(), std::vector<float>(mArea, 0.0f)),
          mFraction(mArea), mTmp(mArea), mRowHits(static_cast<std::size_t>(mN)),
          mRowMaterial(static_cast<std::size_t>(mN)), mAcc(shapes.size()), mOut(mArea),
          mContrast(params.materialGrey - params.airGrey)
    {
        // shapes meeting each slice
        mPerSlice.resize(static_cast<std::size_t>(mN));
        for (int s = 0; s < static_cast<int>(shapes.size()); ++s)
            for (int64_t k = shapes[s].lo[2]; k <= shapes[s].hi[2]; ++k) mPerSlice[k].push_back(s);
    }

    int radius() const { return mRadius; }
    const std::vector<VoidAccumulator>& voids() const { return mAcc; }
    double materialVoxels() const { return mMaterialVoxels; }

    /// Slice k's material fractions, their truth, and the slice blurred along i and j into the ring.
    void computeSlice(int64_t k)
    {
        const std::vector<int>& sliceShapes = mPerSlice[k];
        tbb::parallel_for(int64_t(0), mN, [&](int64_t j) {
            float* f = &mFraction[static_cast<std::size_t>(j * mN)];
            mRowMaterial[j] = rowFractions(mPart, mShapes, sliceShapes, mN, j, k, f, mRowHits[j]);
        });
        accumulate(k);
        blurInSlice(k);
    }

    /// Slice k blurred along k from the ring, to grey values with noise, into the sink.
    void emitSlice(int64_t k, const PartSliceSink& sink)
    {
        const int64_t n = mN;
        const int radius = mRadius;
        const int64_t ringSize = static_cast<int64_t>(mRing.size());
        tbb::parallel_for(int64_t(0), n, [&](int64_t j) {
            uint64_t state =
                mParams.seed * 0x9E3779B97F4A7C15ull ^ (static_cast<uint64_t>(k * n + j) * 0xD1B54A32D192ED03ull);
            Rng noise(splitmix64(state));
            for (int64_t i = 0; i < n; ++i) {
                double m = 0;
                const std::size_t at = static_cast<std::size_t>(j * n + i);
                for (int t = -radius; t <= radius; ++t)
                    if (k + t >= 0 && k + t < n)
                        m += mKernel[t + radius] * mRing[static_cast<std::size_t>((k + t) % ringSize)][at];
                double g = mParams.airGrey + mContrast * m;
                if (mParams.noiseSigma > 0) g += mParams.noiseSigma * noise.normal();
                mOut[at] = static_cast<uint16_t>(std::clamp(std::nearbyint(g), 0.0, 65535.0));
            }
        });
        sink(k, mOut);
    }

private:
    /// Adds slice k's rows to the material volume and to the voids' truth, row by row.
    void accumulate(int64_t k)
    {
        for (int64_t j = 0; j < mN; ++j) {
            mMaterialVoxels += mRowMaterial[j];
            for (const VoidHit& h : mRowHits[j]) {
                VoidAccumulator& a = mAcc[h.shape];
                a.volume += h.fraction;
                a.weighted += Vec3d{double(h.i), double(j), double(k)} * h.fraction;
                if (h.fraction >= 0.5) {
                    ++a.voxels;
                    a.counted.push_back({int32_t(h.i), int32_t(j), int32_t(k)});
                }
            }
        }
    }

    /// Blurs slice k's fractions into its ring slot.
    void blurInSlice(int64_t k)
    {
        const int64_t n = mN;
        const int radius = mRadius;
        // blur along i, then j (zero outside the grid: air)
        tbb::parallel_for(int64_t(0), n, [&](int64_t j) {
            const float* src = &mFraction[static_cast<std::size_t>(j * n)];
            float* dst = &mTmp[static_cast<std::size_t>(j * n)];
            for (int64_t i = 0; i < n; ++i) {
                double s = 0;
                for (int t = -radius; t <= radius; ++t)
                    if (i + t >= 0 && i + t < n) s += mKernel[t + radius] * src[i + t];
                dst[i] = static_cast<float>(s);
            }
        });
        std::vector<float>& slot = mRing[static_cast<std::size_t>(k % static_cast<int64_t>(mRing.size()))];
        tbb::parallel_for(int64_t(0), n, [&](int64_t j) {
            for (int64_t i = 0; i < n; ++i) {
                double s = 0;
                for (int t = -radius; t <= radius; ++t)
                    if (j + t >= 0 && j + t < n)
                        s += mKernel[t + radius] * mTmp[static_cast<std::size_t>((j + t) * n + i)];
                slot[static_cast<std::size_t>(j * n + i)] = static_cast<float>(s);
            }
        });
    }

    const PartShape& mPart;
    const std::vector<Shape>& mShapes;
    const PartPhantomParams& mParams;
    const int64_t mN;
    const std::vector<double> mKernel;
    const int mRadius;
    const std::size_t mArea;
    std::vector<std::vector<int>> mPerSlice;
    std::vector<std::vector<float>> mRing;
    std::vector<float> mFraction, mTmp;
    std::vector<std::vector<VoidHit>> mRowHits;
    std::vector<double> mRowMaterial;
    std::vector<VoidAccumulator> mAcc;
    std::vector<uint16_t> mOut;
    const double mContrast;
    double mMaterialVoxels = 0;
};

/// Largest distance (voxels) between the counted voxels of a void.
double countedExtentVoxels(const std::vector<std::array<int32_t, 3>>& counted)
{
    // boundary of the counted voxels: the farthest pair lies on it
    auto key = [](int32_t x, int32_t y, int32_t z) {
        return (static_cast<uint64_t>(uint32_t(x)) << 42) ^ (static_cast<uint64_t>(uint32_t(y)) << 21) ^
               uint64_t(uint32_t(z));
    };
    std::unordered_set<uint64_t> set;
    set.reserve(counted.size() * 2);
    for (const auto& q : counted) set.insert(key(q[0], q[1], q[2]));
    std::vector<openvdb::Vec3d> boundary;
    for (const auto& q : counted) {
        const int32_t nb[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
        for (const auto& d : nb)
            if (!set.count(key(q[0] + d[0], q[1] + d[1], q[2] + d[2]))) {
                boundary.emplace_back(q[0], q[1], q[2]);
                break;
            }
    }
    return maxVoxelDistance(boundary);
}

/// The truth of void s (index in generation order) from what the slices accumulated.
PartVoidTruth voidTruth(std::size_t s, const Shape& shape, const std::string& kind, const VoidAccumulator& a,
                        const ImageGeometry& geometry, double voxelMm, double voxelVolume)
{
    PartVoidTruth v;
    v.id = static_cast<int>(s) + 1;
    v.kind = kind;
    v.internal = kind != "open_crack";
    v.centerLps = geometry.worldFromIndex(shape.centre);
    v.semiAxesVoxels = shape.axes;
    v.centroidLps = geometry.worldFromIndex(a.volume > 0 ? a.weighted / a.volume : shape.centre);
    v.volumeMm3 = a.volume * voxelVolume;
    v.equivalentDiameterMm = equivalentDiameter(v.volumeMm3);
    v.voxels = a.voxels;
    v.maxExtentMm = countedExtentVoxels(a.counted) * voxelMm;
    return v;
}

} // namespace

PartTruth generatePartPhantom(const PartPhantomParams& paramsIn, const PartSliceSink& sink, Progress* progress)
{
    checkParams(paramsIn);
    const PartPhantomParams params = resolvedParams(paramsIn);
    const int64_t n = params.size;

    PartTruth truth;
    truth.params = params;
    truth.geometry.size = {n, n, n};
    truth.geometry.spacingMm = {params.voxelMm, params.voxelMm, params.voxelMm};
    const double c = 0.5 * static_cast<double>(n - 1);
    truth.geometry.originMm = {-c * params.voxelMm, -c * params.voxelMm, -c * params.voxelMm};
    const PartShape part = partShape(n, c);

    // ---- place the voids
    Rng rng(params.seed * 0x2545F4914F6CDD1Dull + 0x1234567ull);
    PlacedVoids voids;
    placeInternalCrack(rng, part, n, voids);
    placeOpenCrack(rng, part, voids);
    placePores(rng, part, params.pores, n, voids);
    for (Shape& s : voids.shapes) s.computeBounds(n);

    // ---- slices
    PartSlicer slicer(part, voids.shapes, params);
    const int radius = slicer.radius();
    for (int64_t kk = 0; kk < n + radius; ++kk) {
        if (kk < n) slicer.computeSlice(kk);
        if (kk >= radius) slicer.emitSlice(kk - radius, sink);
        if ((kk & 15) == 0) reportProgress(progress, double(kk) / double(n + radius), "part phantom slices");
    }

    // ---- truth
    const double voxelVolume = params.voxelMm * params.voxelMm * params.voxelMm;
    truth.voids.resize(voids.shapes.size());
    tbb::parallel_for(std::size_t(0), voids.shapes.size(), [&](std::size_t s) {
        truth.voids[s] = voidTruth(s, voids.shapes[s], voids.kinds[s], slicer.voids()[s], truth.geometry,
                                   params.voxelMm, voxelVolume);
    });
    truth.materialVolumeMm3 = slicer.materialVoxels() * voxelVolume;
    for (const PartVoidTruth& v : truth.voids)
        if (v.internal) truth.internalVoidVolumeMm3 += v.volumeMm3;
    truth.porosityPercent =
        100.0 * truth.internalVoidVolumeMm3 / (truth.materialVolumeMm3 + truth.internalVoidVolumeMm3);
    reportProgress(progress, 1.0, "part phantom done");
    return truth;
}

} // namespace flyover
