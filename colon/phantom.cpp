// Voxelises the analytic anatomy of phantom_anatomy.h. Each z slice is independent
// (tbb::parallel_for over slabs): the colon's signed distance is splatted from the
// centerline's 2 mm chords into the voxels of their bounding boxes only, then every voxel
// is shaded by painting the structures in order with a one-voxel partial-volume ramp,
// and gets noise from a hash of (seed, voxel index), so the result does not depend on
// the thread count.
#include "colon/phantom.h"

#include "colon/phantom_anatomy.h"
#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

PhantomSize parsePhantomSize(const std::string& name)
{
    if (name == "small")
        return PhantomSize::Small;
    if (name == "medium")
        return PhantomSize::Medium;
    if (name == "full")
        return PhantomSize::Full;
    throw ParameterError("phantom size: unknown value \"" + name +
                         "\"; expected one of small, medium, full");
}

const char* phantomSizeName(PhantomSize size)
{
    switch (size) {
    case PhantomSize::Small: return "small";
    case PhantomSize::Medium: return "medium";
    case PhantomSize::Full: return "full";
    }
    return "unknown";
}

namespace {

using namespace phantom;

constexpr double TWO_PI = 6.283185307179586476925;
constexpr float FAR_MM = std::numeric_limits<float>::max();

/// A piece of the true centerline used to evaluate the colon's signed distance.
struct TubeSegment {
    Vec3d a, d;          ///< start and (end - start), mm
    double invLength2;   ///< 1 / |d|^2
    double radiusA, radiusB;
    double arcA, arcB;   ///< arc length at the ends, mm
    double zMin, zMax;
    double reachMm;      ///< farthest distance from the segment where the colon shows
};

/// The two-sample chords of a tube's axis (the first n of `axis`, 1 mm apart): their sagitta is
/// far below a voxel for the colon's bend radii, and they halve the distance work.
/// radius(i) and arc(i): the tube's radius and arc length (mm) at sample i.
template <typename Radius, typename Arc>
std::vector<TubeSegment> chordsOf(const std::vector<Vec3d>& axis, std::size_t n, const Radius& radius,
                                  const Arc& arc, double voxelMm)
{
    std::vector<TubeSegment> out;
    for (std::size_t i = 0; i + 1 < n; i += 2) {
        const std::size_t j = std::min(i + 2, n - 1);
        TubeSegment t;
        t.a = axis[i];
        t.d = axis[j] - t.a;
        t.invLength2 = 1.0 / dot(t.d, t.d);
        t.radiusA = radius(i);
        t.radiusB = radius(j);
        t.arcA = arc(i);
        t.arcB = arc(j);
        t.zMin = std::min(t.a.z, t.a.z + t.d.z);
        t.zMax = std::max(t.a.z, t.a.z + t.d.z);
        t.reachMm = std::max(t.radiusA, t.radiusB) + COLON_WALL_MM + PERICOLIC_FAT_MM + voxelMm;
        out.push_back(t);
    }
    return out;
}

/// Partial-volume painting: blend towards `hu` by the fraction of the voxel inside
/// the region whose signed distance at the voxel centre is `sdMm` (a linear ramp one
/// voxel wide, the box filter of a planar boundary).
inline void paint(double& value, double hu, double sdMm, double invVoxelMm)
{
    const double coverage = std::clamp(0.5 - sdMm * invVoxelMm, 0.0, 1.0);
    value += (hu - value) * coverage;
}

/// A standard normal sample that depends only on (seed, voxel index): thread-count free.
inline double voxelNoise(uint64_t seedKey, uint64_t voxelIndex)
{
    const uint64_t h = splitmix64(seedKey + splitmix64(voxelIndex));
    const double u1 = (double(h >> 32) + 0.5) * 0x1.0p-32;          // (0, 1)
    const double u2 = double(h & 0xFFFFFFFFull) * 0x1.0p-32;        // [0, 1)
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(TWO_PI * u2);
}

/// Voxel centres of one slice: in lumen fluid, in the colon's own lumen (as if there were
/// no rectal tube), in the rectal tube's air lumen inside the body (part of the mask).
struct SliceCounts {
    int64_t fluid = 0;
    int64_t colonLumen = 0;
    int64_t tubeLumen = 0;
    int64_t ileumLumen = 0;   ///< the terminal ileum's gas (not in the mask)
};

class Voxeliser {
public:
    Voxeliser(const PhantomAnatomy& anatomy, const ImageGeometry& geometry, const PhantomParams& params)
        : mAnatomy(anatomy), mGeometry(geometry), mNoiseHu(params.noiseHu),
          mSeedKey(splitmix64(params.seed ^ 0x5EED0F0015Eull))
    {
        const Vec3d& s = geometry.spacingMm;
        mVoxelMm = (s.x + s.y + s.z) / 3.0;
        mInvVoxelMm = 1.0 / mVoxelMm;

        // Two-millimetre chords of the 1 mm truth curve: their sagitta is far below a
        // voxel for the colon's bend radii, and they halve the distance work. Without a
        // colon there are none, and nothing of it is painted.
        const std::size_t n = params.colon ? anatomy.centerlineMm.size() : 0;
        mSegments = chordsOf(anatomy.centerlineMm, n, [&](std::size_t i) { return anatomy.radiusMm[i]; },
                             [&](std::size_t i) { return double(i) * anatomy.stepMm; }, mVoxelMm);
        // The terminal ileum's chords (variant), splatted apart from the colon's; no arc.
        mIleum = chordsOf(anatomy.ileumMm, anatomy.ileumMm.size(), [&](std::size_t) { return anatomy.ileumRadiusMm; },
                          [](std::size_t) { return -1.0; }, mVoxelMm);
        // Nearest fold for every centerline sample.
        mFoldAt.assign(n, -1);
        for (std::size_t i = 0; i < n && !anatomy.folds.empty(); ++i) {
            const double s = double(i) * anatomy.stepMm;
            int best = 0;
            for (int f = 1; f < int(anatomy.folds.size()); ++f)
                if (std::abs(anatomy.folds[std::size_t(f)].arcMm - s) <
                    std::abs(anatomy.folds[std::size_t(best)].arcMm - s))
                    best = f;
            mFoldAt[i] = best;
        }
        // The centerline samples round each stricture, searched for the nearest one to a point.
        for (const PhantomStricture& st : anatomy.strictures) {
            const auto last = long(n) - 1;
            StrictureSamples w;
            w.stricture = &st;
            w.first = std::clamp(long(std::floor(st.arcStartMm / anatomy.stepMm)) - 40, 0L, last);
            w.last = std::clamp(long(std::ceil(st.arcEndMm / anatomy.stepMm)) + 40, 0L, last);
            w.middleMm = anatomy.centerlineMm[std::size_t((w.first + w.last) / 2)];
            w.reachMm = 0.5 * double(w.last - w.first) * anatomy.stepMm + 60.0;
            mStrictures.push_back(w);
        }
    }

    /// Fills slices [k0, k1) of `ct` and `truth`; counts[k] gets the voxel counts of slice k.
    void run(int64_t k0, int64_t k1, Image3<int16_t>& ct, Image3<uint8_t>& truth,
             SliceCounts* counts) const
    {
        const std::size_t sliceVoxels = std::size_t(mGeometry.size[0] * mGeometry.size[1]);
        std::vector<float> bestSd(sliceVoxels);
        std::vector<int32_t> bestSegment(sliceVoxels);
        std::vector<float> bestT(sliceVoxels);
        std::vector<float> ileumSd, ileumT;
        std::vector<int32_t> ileumSegment;
        if (!mIleum.empty()) {
            ileumSd.resize(sliceVoxels);
            ileumT.resize(sliceVoxels);
            ileumSegment.resize(sliceVoxels);
        }
        for (int64_t k = k0; k < k1; ++k) {
            splatTube(mSegments, k, bestSd, bestSegment, bestT);
            if (!mIleum.empty()) splatTube(mIleum, k, ileumSd, ileumSegment, ileumT);
            counts[k] = shadeSlice(k, bestSd, bestSegment, bestT, ileumSd, ct, truth);
        }
    }

private:
    /// For every voxel of slice k within reach of a tube (the colon, or the ileum): the least
    /// (distance to its axis - radius) over its segments, and where on the curve it is
    /// reached. Iterates segments and touches only the voxels in their bounding boxes.
    void splatTube(const std::vector<TubeSegment>& segments, int64_t k, std::vector<float>& bestSd,
                   std::vector<int32_t>& bestSegment, std::vector<float>& bestT) const
    {
        std::fill(bestSd.begin(), bestSd.end(), FAR_MM);
        const auto& g = mGeometry;
        const int64_t nx = g.size[0], ny = g.size[1];
        const double z = g.originMm.z + double(k) * g.spacingMm.z;
        for (std::size_t si = 0; si < segments.size(); ++si) {
            const TubeSegment& t = segments[si];
            const double dz = std::max({0.0, t.zMin - z, z - t.zMax});
            if (dz >= t.reachMm)
                continue;
            const double half = std::sqrt(t.reachMm * t.reachMm - dz * dz);
            const Vec3d b = t.a + t.d;
            const auto lo = [](double v, double o, double s) { return int64_t(std::ceil((v - o) / s)); };
            const auto hi = [](double v, double o, double s) { return int64_t(std::floor((v - o) / s)); };
            const int64_t i0 = std::max<int64_t>(0, lo(std::min(t.a.x, b.x) - half, g.originMm.x, g.spacingMm.x));
            const int64_t i1 = std::min<int64_t>(nx - 1, hi(std::max(t.a.x, b.x) + half, g.originMm.x, g.spacingMm.x));
            const int64_t j0 = std::max<int64_t>(0, lo(std::min(t.a.y, b.y) - half, g.originMm.y, g.spacingMm.y));
            const int64_t j1 = std::min<int64_t>(ny - 1, hi(std::max(t.a.y, b.y) + half, g.originMm.y, g.spacingMm.y));
            const double wz = z - t.a.z;
            for (int64_t j = j0; j <= j1; ++j) {
                const double wy = g.originMm.y + double(j) * g.spacingMm.y - t.a.y;
                for (int64_t i = i0; i <= i1; ++i) {
                    const double wx = g.originMm.x + double(i) * g.spacingMm.x - t.a.x;
                    const double along = std::clamp((wx * t.d.x + wy * t.d.y + wz * t.d.z) * t.invLength2, 0.0, 1.0);
                    const double qx = wx - t.d.x * along, qy = wy - t.d.y * along, qz = wz - t.d.z * along;
                    const double sd = std::sqrt(qx * qx + qy * qy + qz * qz) -
                                      (t.radiusA + (t.radiusB - t.radiusA) * along);
                    const std::size_t v = std::size_t(i + nx * j);
                    if (sd < bestSd[v]) {
                        bestSd[v] = float(sd);
                        bestSegment[v] = int32_t(si);
                        bestT[v] = float(along);
                    }
                }
            }
        }
    }

    /// Signed distance to the colon lumen: the tube minus folds, polyps and collapsed
    /// stretches. `arcMm` receives the arc length of the nearest centerline point.
    double lumenSignedDistanceMm(const Vec3d& p, double tubeSd, int32_t segment, float along,
                                 double& arcMm) const
    {
        double sd = tubeSd;
        const TubeSegment& t = mSegments[std::size_t(segment)];
        const double arc = t.arcA + (t.arcB - t.arcA) * double(along);
        arcMm = arc;
        const auto sample = std::size_t(std::clamp<long>(std::lround(arc / mAnatomy.stepMm), 0L,
                                                          long(mFoldAt.size()) - 1));
        // A fold belongs to its own stretch of tube: beyond its rim it is a slab along its
        // plane, which crossed other loops of the colon that the plane met (the rectum, whose
        // nearest fold in arc is the sigmoid's first, 80-90 mm away, lost a slab across its
        // whole lumen when --touching bent the sigmoid: the truth axis ran through tissue).
        const int fi = mFoldAt[sample];
        const HaustralFold* fold = fi >= 0 ? &mAnatomy.folds[std::size_t(fi)] : nullptr;
        if (fold && std::abs(arc - fold->arcMm) <= fold->tubeRadiusMm + fold->thicknessMm) {
            const HaustralFold& f = *fold;
            const auto c = std::size_t(f.index);
            const Vec3d& centre = mAnatomy.centerlineMm[c];
            const double u = dot(p - centre, mAnatomy.tangent[c]);
            if (std::abs(u) - 0.5 * f.thicknessMm < mVoxelMm) {
                const double foldSd = f.signedDistanceMm(p, centre, mAnatomy.tangent[c],
                                                         mAnatomy.normal[c], mAnatomy.binormal[c]);
                sd = std::max(sd, -foldSd);
            }
        }
        for (const PhantomPolyp& polyp : mAnatomy.polyps)
            sd = std::max(sd, polyp.radiusMm - distance(p, polyp.centerMm));
        // A collapsed stretch is a slab in arc length (flat ends across the tube).
        for (const PhantomCollapse& c : mAnatomy.collapsed)
            sd = std::max(sd, std::min(arc - c.arcStartMm, c.arcEndMm - arc));
        // A stricture: where the nearest centerline sample lies in it, the lumen is no wider
        // than the narrowed radius there. (The tube's own distance is the union of its chords'
        // cones, whose round ends, a full radius wide, would fill a narrowing shorter than the
        // radius.) Only for points of the tube round it (their nearest chord's arc within the
        // samples searched): the nearest of those samples to a point of another loop nearby
        // may lie in the stricture too, and that loop lost a slab of its lumen.
        for (const StrictureSamples& w : mStrictures) {
            if (arc < double(w.first) * mAnatomy.stepMm || arc > double(w.last) * mAnatomy.stepMm) continue;
            if (distance(p, w.middleMm) > w.reachMm) continue;
            long nearest = w.first;
            double nearestMm = distance(p, mAnatomy.centerlineMm[std::size_t(w.first)]);
            for (long i = w.first + 1; i <= w.last; ++i) {
                const double d = distance(p, mAnatomy.centerlineMm[std::size_t(i)]);
                if (d < nearestMm) {
                    nearestMm = d;
                    nearest = i;
                }
            }
            const double at = double(nearest) * mAnatomy.stepMm;
            if (at > w.stricture->arcStartMm && at < w.stricture->arcEndMm)
                sd = std::max(sd, nearestMm - mAnatomy.radiusMm[std::size_t(nearest)]);
        }
        return sd;
    }

    /// What fills the lumen at p: air, or tagged fluid below its pool's level, with a
    /// one-voxel partial-volume ramp across the level. `inFluid`: the point is in fluid.
    double lumenContentHu(const Vec3d& p, double arcMm, bool& inFluid) const
    {
        inFluid = false;
        for (const PhantomFluidPool& pool : mAnatomy.fluidPools) {
            if (arcMm < pool.arcStartMm || arcMm > pool.arcEndMm)
                continue;
            const double levelSd = (pool.levelYMm - p.y) * pool.downY;  // negative in the fluid (below the level)
            inFluid = levelSd < 0;
            const double coverage = std::clamp(0.5 - levelSd * mInvVoxelMm, 0.0, 1.0);
            return AIR_HU + (pool.hu - AIR_HU) * coverage;
        }
        return AIR_HU;
    }

    /// Shades slice k; returns its voxel counts.
    SliceCounts shadeSlice(int64_t k, const std::vector<float>& bestSd, const std::vector<int32_t>& bestSegment,
                           const std::vector<float>& bestT, const std::vector<float>& ileumSds,
                           Image3<int16_t>& ct, Image3<uint8_t>& truth) const
    {
        SliceCounts counts;
        const auto& g = mGeometry;
        const int64_t nx = g.size[0], ny = g.size[1];
        const double z = g.originMm.z + double(k) * g.spacingMm.z;
        const double h = mVoxelMm, invH = mInvVoxelMm;

        // Structures that reach this slice.
        std::vector<const Ellipsoid*> ellipsoids;  // lungs then gas pockets
        std::vector<double> ellipsoidHu;
        const auto addIfNear = [&](const Ellipsoid& e, double hu) {
            const double reach = std::max({e.semiAxesMm.x, e.semiAxesMm.y, e.semiAxesMm.z}) + h;
            if (std::abs(z - e.centerMm.z) < reach) {
                ellipsoids.push_back(&e);
                ellipsoidHu.push_back(hu);
            }
        };
        for (const Ellipsoid& lung : mAnatomy.lungs)
            addIfNear(lung, LUNG_HU);
        for (const Ellipsoid& pocket : mAnatomy.gasPockets)
            addIfNear(pocket, AIR_HU);
        // Contact channels and the rectal tube that reach this slice (variants).
        std::vector<const PhantomContact*> contacts;
        for (const PhantomContact& c : mAnatomy.contacts) {
            const double reach = std::max(c.halfLengthAMm, c.halfLengthBMm) + c.widthMm + h;
            if (std::abs(z - c.positionMm.z) < reach)
                contacts.push_back(&c);
        }
        const PhantomRectalTube& tube = mAnatomy.rectalTube;
        bool tubeNear = false;
        double tubeBox[4] = {1e300, -1e300, 1e300, -1e300};  // x0, x1, y0, y1
        if (mAnatomy.hasRectalTube) {
            const double reach = tube.outerRadiusMm + h;
            for (std::size_t s = 0; s + 1 < tube.axisMm.size(); ++s) {
                const Vec3d& a = tube.axisMm[s];
                const Vec3d& b = tube.axisMm[s + 1];
                if (z < std::min(a.z, b.z) - reach || z > std::max(a.z, b.z) + reach)
                    continue;
                tubeNear = true;
                tubeBox[0] = std::min({tubeBox[0], a.x - reach, b.x - reach});
                tubeBox[1] = std::max({tubeBox[1], a.x + reach, b.x + reach});
                tubeBox[2] = std::min({tubeBox[2], a.y - reach, b.y - reach});
                tubeBox[3] = std::max({tubeBox[3], a.y + reach, b.y + reach});
            }
        }
        // Intervertebral discs: slabs centred every DISC_PERIOD_MM from z = 0.
        const double discSlabSd = std::abs(std::remainder(z, DISC_PERIOD_MM)) - 0.5 * DISC_THICKNESS_MM;

        for (int64_t j = 0; j < ny; ++j) {
            const double y = g.originMm.y + double(j) * g.spacingMm.y;
            for (int64_t i = 0; i < nx; ++i) {
                const double x = g.originMm.x + double(i) * g.spacingMm.x;
                const std::size_t v2 = std::size_t(i + nx * j);
                const std::size_t v = ct.linearIndex(i, j, k);
                double hu = AIR_HU;
                uint8_t inLumen = 0;
                const double skinSd = bodySignedDistanceMm(x, y);
                if (skinSd < h) {  // everything but air lies inside the body
                    const Vec3d p{x, y, z};
                    paint(hu, SOFT_TISSUE_HU, skinSd, invH);
                    paint(hu, FAT_HU, std::max(skinSd, -bodyInnerSignedDistanceMm(x, y)), invH);
                    // The colon's tube, or the ileum's where that lies nearer (variant): one
                    // wall round both, the colon's lumen (folds, polyps, fluid) and the
                    // ileum's air joined through the valve.
                    const double colonSd = bestSd[v2];
                    const double ileumSd = ileumSds.empty() ? double(FAR_MM) : double(ileumSds[v2]);
                    const double tubeSd = std::min(colonSd, ileumSd);
                    paint(hu, FAT_HU, tubeSd - (COLON_WALL_MM + PERICOLIC_FAT_MM), invH);

                    const double spineSd = std::hypot(x, y - SPINE_CENTER_Y_MM) - SPINE_RADIUS_MM;
                    if (spineSd < h) {
                        paint(hu, CORTICAL_BONE_HU, spineSd, invH);
                        paint(hu, CANCELLOUS_BONE_HU, spineSd + SPINE_CORTEX_MM, invH);
                        paint(hu, DISC_HU, std::max(spineSd, discSlabSd), invH);
                    }
                    for (std::size_t e = 0; e < ellipsoids.size(); ++e)
                        paint(hu, ellipsoidHu[e], ellipsoids[e]->signedDistanceMm(p), invH);

                    if (tubeSd < COLON_WALL_MM + h) {
                        paint(hu, SOFT_TISSUE_HU, tubeSd - COLON_WALL_MM, invH);
                        if (tubeSd < h) {
                            double arc = 0;
                            const double lumenSd = colonSd < h ? lumenSignedDistanceMm(p, colonSd, bestSegment[v2],
                                                                                        bestT[v2], arc)
                                                               : colonSd;
                            bool inFluid = false;
                            if (lumenSd <= ileumSd)
                                paint(hu, lumenContentHu(p, arc, inFluid), lumenSd, invH);
                            else
                                paint(hu, AIR_HU, ileumSd, invH);
                            inLumen = lumenSd < 0 ? 1 : 0;
                            counts.fluid += inLumen && inFluid ? 1 : 0;
                            counts.ileumLumen += !inLumen && ileumSd < 0 ? 1 : 0;
                        }
                    }
                    // A contact: a channel of air through both walls. Voxels whose centre is
                    // in it are air (no partial volume inside, so a 1-voxel channel stays
                    // dark in the CT); the ramp lies outside.
                    for (const PhantomContact* c : contacts) {
                        const double contactSd = contactSignedDistanceMm(*c, p);
                        if (contactSd < h) {
                            paint(hu, AIR_HU, contactSd - 0.5 * h, invH);
                            inLumen = contactSd < 0 ? 1 : inLumen;
                        }
                    }
                }
                counts.colonLumen += inLumen;
                // The rectal tube lies over everything, inside and outside the body: a plastic
                // wall, and air in its lumen. Its lumen inside the body is in the mask (as a
                // segmentation of the colon's air would take it); its wall is not.
                if (tubeNear && x > tubeBox[0] && x < tubeBox[1] && y > tubeBox[2] && y < tubeBox[3]) {
                    const TubeDistance d = rectalTubeDistance(tube, Vec3d{x, y, z});
                    const double wallSd = std::max(d.axisMm - tube.outerRadiusMm, d.beyondTipMm);
                    if (wallSd < h) {
                        // Fractions of the voxel: the solid rod (wall + lumen) and its lumen;
                        // the wall is the difference. At the open tip both are partial
                        // alike and the lumen's cross-section there holds no wall (painting
                        // the rod's wall and then the air over it left a quarter of the wall
                        // there: a cap of -700 HU that closed the open tip to the air).
                        const double airSd = std::max(d.axisMm - tube.innerRadiusMm, d.beyondTipMm);
                        const double rod = std::clamp(0.5 - wallSd * invH, 0.0, 1.0);
                        const double air = std::min(rod, std::clamp(0.5 - airSd * invH, 0.0, 1.0));
                        hu = hu * (1.0 - rod) + tube.wallHu * (rod - air) + AIR_HU * air;
                        if (wallSd < 0) {
                            const bool tubeAir = airSd < 0 && skinSd < 0;
                            inLumen = tubeAir ? 1 : 0;
                            counts.tubeLumen += tubeAir ? 1 : 0;
                        }
                    }
                }
                hu += mNoiseHu * voxelNoise(mSeedKey, uint64_t(v));
                const double rounded = std::clamp(std::round(hu), -32768.0, 32767.0);
                ct.voxels[v] = int16_t(rounded);
                truth.voxels[v] = inLumen;
            }
        }
        return counts;
    }

    const PhantomAnatomy& mAnatomy;
    const ImageGeometry& mGeometry;
    double mNoiseHu;
    uint64_t mSeedKey;
    double mVoxelMm = 1, mInvVoxelMm = 1;
    std::vector<TubeSegment> mSegments;
    std::vector<TubeSegment> mIleum;   ///< the terminal ileum's chords (variant)
    std::vector<int> mFoldAt;
    struct StrictureSamples {
        const PhantomStricture* stricture = nullptr;
        long first = 0, last = 0;  ///< centerline samples searched (40 mm either side)
        Vec3d middleMm;
        double reachMm = 0;        ///< points farther than this from middleMm are not near it
    };
    std::vector<StrictureSamples> mStrictures;
};

} // namespace

namespace {

/// The image stored with its index axes along the direction columns `dir` (each +-1 along
/// one world axis), the world position of every voxel unchanged. `image` is the identity-
/// direction image makePhantom voxelises.
template <typename T>
void reorient(Image3<T>& image, const Mat3d& dir)
{
    const ImageGeometry& from = image.geometry;
    ImageGeometry to = from;
    std::array<int, 3> axis{};     // world axis (= old index axis) of each new index axis
    std::array<bool, 3> flip{};    // the new axis runs against it
    for (int c = 0; c < 3; ++c) {
        for (int r = 0; r < 3; ++r)
            if (dir[std::size_t(r)][std::size_t(c)] != 0.0) axis[std::size_t(c)] = r;
        const int a = axis[std::size_t(c)];
        flip[std::size_t(c)] = dir[std::size_t(a)][std::size_t(c)] < 0.0;
        to.size[std::size_t(c)] = from.size[std::size_t(a)];
        to.spacingMm[c] = from.spacingMm[a];
    }
    to.direction = dir;
    // The old index of new index n, along old axis a.
    const auto oldIndex = [&](const std::array<int64_t, 3>& n) {
        std::array<int64_t, 3> o{};
        for (int c = 0; c < 3; ++c) {
            const int a = axis[std::size_t(c)];
            o[std::size_t(a)] = flip[std::size_t(c)] ? from.size[std::size_t(a)] - 1 - n[std::size_t(c)] : n[std::size_t(c)];
        }
        return o;
    };
    const std::array<int64_t, 3> o0 = oldIndex({0, 0, 0});
    to.originMm = from.worldFromIndex(Vec3d{double(o0[0]), double(o0[1]), double(o0[2])});
    std::vector<T> voxels(image.voxels.size());
    tbb::parallel_for(int64_t(0), to.size[2], [&](int64_t k) {
        for (int64_t j = 0; j < to.size[1]; ++j)
            for (int64_t i = 0; i < to.size[0]; ++i) {
                const std::array<int64_t, 3> o = oldIndex({i, j, k});
                voxels[std::size_t(i + to.size[0] * (j + to.size[1] * k))] = image.at(o[0], o[1], o[2]);
            }
    });
    image.voxels = std::move(voxels);
    image.geometry = to;
}

} // namespace

Mat3d orientationDirection(const std::string& code)
{
    Mat3d dir{};
    std::array<bool, 3> used{};
    bool ok = code.size() == 3;
    for (std::size_t c = 0; ok && c < 3; ++c) {
        const char letter = char(std::toupper(static_cast<unsigned char>(code[c])));
        static const std::string letters = "LRPASI";  // + and - of LPS x, y, z
        const std::size_t at = letters.find(letter);
        ok = at != std::string::npos && !used[at / 2];
        if (!ok) break;
        used[at / 2] = true;
        dir[at / 2][c] = at % 2 == 0 ? 1.0 : -1.0;
    }
    if (!ok)
        throw ParameterError("phantom orientation: expected three letters naming where the index axes i, j, k "
                             "point, one of L/R, one of P/A and one of S/I (e.g. LPS, RAS, LAS, SLP), got '" +
                             code + "'");
    return dir;
}

Phantom makePhantom(const PhantomParams& params)
{
    const Mat3d storedDirection = orientationDirection(params.orientation);
    if (params.prone && !params.fluid)
        throw ParameterError("phantom prone: only changes where the tagged fluid lies; give it with fluid");
    if (!(params.noiseHu >= 0.0) || !std::isfinite(params.noiseHu))
        throw ParameterError("phantom noiseHu: expected a finite value >= 0, got " +
                             std::to_string(params.noiseHu));
    if (params.touching < 0 || params.touching > PHANTOM_MAX_CONTACTS)
        throw ParameterError("phantom touching: expected 0.." + std::to_string(PHANTOM_MAX_CONTACTS) +
                             " contacts, got " + std::to_string(params.touching));
    const ImageGeometry geometry = phantomImageGeometry(params);
    AnatomyOptions options;
    options.redundant = params.redundant;
    options.touching = params.touching;
    options.voxelMm = geometry.spacingMm;
    options.rectalTube = params.rectalTube;
    options.wideRectum = params.wideRectum;
    if (params.polypDiametersMm)
        for (double d : *params.polypDiametersMm)
            if (!(d >= 2.0 && d <= 30.0))
                throw ParameterError("phantom polyp diameters: each must lie in [2, 30] mm, got " + std::to_string(d));
    options.polypDiametersMm = params.polypDiametersMm;
    PhantomAnatomy anatomy = buildPhantomAnatomy(params.seed, options);
    if (params.collapse)
        addCollapses(anatomy, params.seed);
    if (params.stricture && params.colon)
        addStricture(anatomy, params.seed,
                     std::max({geometry.spacingMm.x, geometry.spacingMm.y, geometry.spacingMm.z}));
    if (params.fluid)
        addFluidPools(anatomy, params.seed, params.prone);
    if (params.ilealReflux && params.colon)
        addIleum(anatomy);

    Phantom out;
    out.ct.geometry = out.truthLumen.geometry = geometry;
    const auto& g = out.ct.geometry;
    out.ct.voxels.assign(std::size_t(g.voxelCount()), 0);
    out.truthLumen.voxels.assign(std::size_t(g.voxelCount()), 0);

    const Voxeliser voxeliser(anatomy, g, params);
    // Voxel counts per slice, summed in slice order afterwards (thread-count free).
    std::vector<SliceCounts> perSlice(std::size_t(g.size[2]));
    tbb::parallel_for(tbb::blocked_range<int64_t>(0, g.size[2], 1),
                      [&](const tbb::blocked_range<int64_t>& r) {
                          voxeliser.run(r.begin(), r.end(), out.ct, out.truthLumen, perSlice.data());
                      });

    PhantomTruth& truth = out.truth;
    if (params.colon) {
        truth.centerlineMm = anatomy.centerlineMm;
        truth.radiusMm = anatomy.radiusMm;
        truth.segment = anatomy.segment;
        truth.polyps = anatomy.polyps;
        truth.collapsed = anatomy.collapsed;
        truth.strictures = anatomy.strictures;
        truth.fluidPools = anatomy.fluidPools;
        truth.contacts = anatomy.contacts;
        truth.hasRectalTube = anatomy.hasRectalTube;
        truth.rectalTube = anatomy.rectalTube;
        truth.ileumMm = anatomy.ileumMm;
        truth.ileumRadiusMm = anatomy.ileumRadiusMm;
        truth.ileumValveArcMm = anatomy.ileumValveArcMm;
    }
    const double voxelMl = g.spacingMm.x * g.spacingMm.y * g.spacingMm.z / 1000.0;
    const auto lumenVoxels = std::count(out.truthLumen.voxels.begin(), out.truthLumen.voxels.end(), uint8_t(1));
    truth.lumenVolumeMl = double(lumenVoxels) * voxelMl;
    SliceCounts total;
    for (const SliceCounts& c : perSlice) {
        total.fluid += c.fluid;
        total.colonLumen += c.colonLumen;
        total.tubeLumen += c.tubeLumen;
        total.ileumLumen += c.ileumLumen;
    }
    truth.fluidVolumeMl = double(total.fluid) * voxelMl;
    truth.colonLumenVolumeMl = double(total.colonLumen) * voxelMl;
    truth.tubeLumenVolumeMl = double(total.tubeLumen) * voxelMl;
    truth.ileumLumenVolumeMl = double(total.ileumLumen) * voxelMl;
    if (storedDirection != identityMat3()) {
        reorient(out.ct, storedDirection);
        reorient(out.truthLumen, storedDirection);
    }
    return out;
}

ImageGeometry phantomImageGeometry(const PhantomParams& params)
{
    const Vec3d& s = params.spacingMm;
    if (s.x == 0.0 && s.y == 0.0 && s.z == 0.0)
        return phantomGeometry(params.size);
    for (int c = 0; c < 3; ++c)
        if (!std::isfinite(s[c]) || s[c] < PHANTOM_MIN_SPACING_MM || s[c] > PHANTOM_MAX_SPACING_MM) {
            std::ostringstream msg;
            msg << "phantom spacing: expected three voxel sizes in [" << PHANTOM_MIN_SPACING_MM << ", "
                << PHANTOM_MAX_SPACING_MM << "] mm, got " << s.x << "," << s.y << "," << s.z;
            throw ParameterError(msg.str());
        }
    // The same field of view as every size: 400 x 400 x 375 mm centred on the origin.
    const ImageGeometry reference = phantomGeometry(PhantomSize::Small);
    ImageGeometry g;
    for (int c = 0; c < 3; ++c) {
        const double fov = double(reference.size[std::size_t(c)]) * reference.spacingMm[c];
        g.size[std::size_t(c)] = std::max<int64_t>(1, std::llround(fov / s[c]));
        g.spacingMm[c] = s[c];
        g.originMm[c] = -0.5 * double(g.size[std::size_t(c)] - 1) * s[c];
    }
    g.direction = identityMat3();
    return g;
}

} // namespace flyover
