// The phantom's harder variants on a built anatomy: collapses, a stricture, fluid pools and the
// terminal ileum (phantom_anatomy.h).
#include "colon/phantom_anatomy.h"
#include "colon/phantom_anatomy_detail.h"

#include "volume/error.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace flyover::phantom {

using namespace detail;

void addCollapses(PhantomAnatomy& a, uint64_t seed)
{
    std::mt19937_64 rng(splitmix64(seed ^ 0xC011A95EDull));
    const int count = 1 + int(rng() % 2);
    const double sigmoidStart = double(firstIndexOf(a, "sigmoid")) * a.stepMm;
    const double descendingStart = double(firstIndexOf(a, "descending")) * a.stepMm;
    const auto clearOfPolyps = [&](double s0, double s1) {
        for (const PhantomPolyp& p : a.polyps)
            if (p.arcMm > s0 - p.radiusMm - 10.0 && p.arcMm < s1 + p.radiusMm + 10.0)
                return false;
        return true;
    };
    for (int attempt = 0; attempt < 20000; ++attempt) {
        std::vector<PhantomCollapse> stretches;
        PhantomCollapse first;
        first.arcStartMm = std::round(uniform(rng, sigmoidStart + 90.0, sigmoidStart + 230.0));
        first.arcEndMm = first.arcStartMm + std::round(uniform(rng, 20.0, 40.0));
        stretches.push_back(first);
        if (count == 2) {
            PhantomCollapse second;
            second.arcStartMm = first.arcEndMm + std::round(uniform(rng, 100.0, 140.0));
            second.arcEndMm = second.arcStartMm + std::round(uniform(rng, 20.0, 40.0));
            stretches.push_back(second);
        }
        bool ok = stretches.back().arcEndMm < descendingStart - 40.0;
        for (const PhantomCollapse& c : stretches) {
            ok = ok && clearOfPolyps(c.arcStartMm, c.arcEndMm);
            for (const PhantomContact& k : a.contacts)
                for (double arc : {k.arcAMm, k.arcBMm})
                    ok = ok && (arc < c.arcStartMm - POLYP_CONTACT_CLEARANCE_MM ||
                                arc > c.arcEndMm + POLYP_CONTACT_CLEARANCE_MM);
        }
        if (ok) {
            a.collapsed = stretches;
            return;
        }
    }
    throw std::logic_error("phantom anatomy: could not place a collapsed stretch clear of the polyps");
}

void addStricture(PhantomAnatomy& a, uint64_t seed, double voxelMm)
{
    std::mt19937_64 rng(splitmix64(seed ^ 0x57121C7E5ull));
    const double minRadius = std::max(3.0, 1.6 * voxelMm);
    double first = -1, last = -1;  // the transverse colon's arc range
    for (std::size_t i = 0; i < a.segment.size(); ++i)
        if (a.segment[i] == "transverse") {
            if (first < 0) first = double(i) * a.stepMm;
            last = double(i) * a.stepMm;
        }
    if (first < 0) throw std::logic_error("phantom anatomy: no transverse colon for the stricture");
    constexpr double SHOULDER_MM = 3.0;  // abrupt: the narrowing is nearly all reached in 3 mm
    for (int attempt = 0; attempt < 20000; ++attempt) {
        const double halfFlat = std::round(uniform(rng, 4.0, 6.0));
        const double halfWidth = halfFlat + SHOULDER_MM;
        const double mid = std::round(uniform(rng, first + 30.0 + halfWidth, last - 30.0 - halfWidth));
        const double s0 = mid - halfWidth, s1 = mid + halfWidth;
        bool ok = true;
        for (const PhantomPolyp& p : a.polyps)
            ok = ok && (p.arcMm < s0 - p.radiusMm - 10.0 || p.arcMm > s1 + p.radiusMm + 10.0);
        for (const PhantomContact& k : a.contacts)
            for (double arc : {k.arcAMm, k.arcBMm})
                ok = ok && (arc < s0 - POLYP_CONTACT_CLEARANCE_MM || arc > s1 + POLYP_CONTACT_CLEARANCE_MM);
        for (const PhantomCollapse& c : a.collapsed) ok = ok && (c.arcEndMm < s0 - 20.0 || c.arcStartMm > s1 + 20.0);
        if (!ok) continue;
        for (std::size_t i = 0; i < a.radiusMm.size(); ++i) {
            const double off = std::abs(double(i) * a.stepMm - mid);
            if (off >= halfWidth) continue;
            const double u = std::max(0.0, off - halfFlat) / SHOULDER_MM, c = std::sin(0.5 * PI * u);
            const double R = a.radiusMm[i];
            a.radiusMm[i] = std::min(R, minRadius + (R - minRadius) * c * c);
        }
        std::vector<HaustralFold> folds;
        for (const HaustralFold& f : a.folds)
            if (f.arcMm + f.thicknessMm < s0 || f.arcMm - f.thicknessMm > s1) folds.push_back(f);
        a.folds = std::move(folds);
        a.strictures = {PhantomStricture{s0, s1, minRadius}};
        return;
    }
    throw std::logic_error("phantom anatomy: could not place the stricture clear of the polyps and contacts");
}

namespace {

/// The prone pools: anterior of their levels, in the sigmoid and the transverse colon.
void addProneFluidPools(PhantomAnatomy& a, std::mt19937_64& rng)
{
    const double ranges[2][2] = {
        {double(firstIndexOf(a, "sigmoid")) * a.stepMm, double(firstIndexOf(a, "descending")) * a.stepMm},
        {double(firstIndexOf(a, "transverse")) * a.stepMm, double(firstIndexOf(a, "ascending")) * a.stepMm},
    };
    // How far (mm, LPS y) the lumen's most anterior wall reaches at sample i.
    const auto front = [&](std::size_t i) { return a.centerlineMm[i].y - a.radiusMm[i]; };
    for (const auto& r : ranges) {
        std::size_t deepest = sampleAt(a, r[0]);
        for (std::size_t i = sampleAt(a, r[0]); i <= sampleAt(a, r[1]); ++i)
            if (front(i) < front(deepest)) deepest = i;
        PhantomFluidPool pool;
        pool.downY = -1.0;
        const double depthMm = uniform(rng, 0.25, 0.45) * 2.0 * a.radiusMm[deepest];
        pool.levelYMm = front(deepest) + depthMm;
        pool.hu = std::round(uniform(rng, 300.0, 600.0));
        // The pool runs along the colon as far as its lumen reaches below the level, and ends
        // where the lumen lies 2 mm clear of it (no vertical fluid face).
        std::size_t lo = deepest, hi = deepest;
        while (lo > 0 && front(lo - 1) < pool.levelYMm + 2.0) --lo;
        while (hi + 1 < a.centerlineMm.size() && front(hi + 1) < pool.levelYMm + 2.0) ++hi;
        pool.arcStartMm = double(lo) * a.stepMm;
        pool.arcEndMm = double(hi) * a.stepMm;
        bool overlaps = false;
        for (const PhantomFluidPool& p : a.fluidPools)
            overlaps = overlaps || (pool.arcStartMm <= p.arcEndMm && p.arcStartMm <= pool.arcEndMm);
        if (!overlaps) a.fluidPools.push_back(pool);
    }
    std::sort(a.fluidPools.begin(), a.fluidPools.end(),
              [](const PhantomFluidPool& x, const PhantomFluidPool& y) { return x.arcStartMm < y.arcStartMm; });
}

} // namespace

void addFluidPools(PhantomAnatomy& a, uint64_t seed, bool prone)
{
    std::mt19937_64 rng(splitmix64(seed ^ 0xF1D0F1D0ull));
    if (prone) {
        addProneFluidPools(a, rng);
        return;
    }
    const double end = a.lengthMm();
    // Arc ranges of the dependent (posterior-lying) stretches of a supine patient's colon.
    const double ranges[3][2] = {
        {0.0, double(firstIndexOf(a, "sigmoid")) * a.stepMm},
        {double(firstIndexOf(a, "descending")) * a.stepMm - 60.0,
         double(firstIndexOf(a, "transverse")) * a.stepMm},
        {double(firstIndexOf(a, "ascending")) * a.stepMm - 20.0, end},
    };
    for (const auto& r : ranges) {
        PhantomFluidPool pool;
        pool.arcStartMm = r[0];
        pool.arcEndMm = r[1];
        // The deepest point of the stretch: the most posterior lumen wall.
        std::size_t deepest = sampleAt(a, r[0]);
        for (std::size_t i = sampleAt(a, r[0]); i <= sampleAt(a, r[1]); ++i)
            if (a.centerlineMm[i].y + a.radiusMm[i] > a.centerlineMm[deepest].y + a.radiusMm[deepest])
                deepest = i;
        const double depthMm = uniform(rng, 0.25, 0.45) * 2.0 * a.radiusMm[deepest];
        pool.levelYMm = a.centerlineMm[deepest].y + a.radiusMm[deepest] - depthMm;
        pool.hu = std::round(uniform(rng, 300.0, 600.0));
        // A pool must end where the lumen rises clear of its level (no vertical fluid face),
        // except at the ends of the colon.
        for (double s : {r[0], r[1]}) {
            const std::size_t i = sampleAt(a, s);
            if (s > 0.0 && s < end && a.centerlineMm[i].y + a.radiusMm[i] + 2.0 > pool.levelYMm)
                throw std::logic_error("phantom anatomy: a fluid pool is cut at arc " +
                                       std::to_string(s) + " mm");
        }
        a.fluidPools.push_back(pool);
    }
}

void addIleum(PhantomAnatomy& a)
{
    constexpr double RADIUS_MM = 11.0, VALVE_ABOVE_END_MM = 50.0;
    const std::size_t n = a.centerlineMm.size();
    const auto valve = std::size_t(double(n - 1) - VALVE_ABOVE_END_MM / a.stepMm);
    const Vec3d c = a.centerlineMm[valve];
    // From the cecum's axis out through its medial wall (+x: towards the patient's left),
    // then down into the right pelvis and back towards the right side wall.
    const std::vector<Vec3d> control = {c,
                                        c + Vec3d{38.0, 0.0, 0.0},
                                        {-45.0, 10.0, -84.0},
                                        {-47.0, 10.0, -106.0},
                                        {-55.0, 8.0, -126.0},
                                        {-70.0, 4.0, -138.0},
                                        {-86.0, 0.0, -143.0}};
    // The colon's spline through the control points, sampled every 1 mm of arc.
    const ChordCubicSpline spline(control);
    std::vector<Vec3d> dense;
    std::vector<double> denseArc;
    constexpr int DENSE_PER_SPAN = 256;
    for (std::size_t span = 0; span + 1 < control.size(); ++span)
        for (int k = span == 0 ? 0 : 1; k <= DENSE_PER_SPAN; ++k) {
            const Vec3d p = spline.at(span, double(k) / DENSE_PER_SPAN);
            denseArc.push_back(dense.empty() ? 0.0 : denseArc.back() + distance(dense.back(), p));
            dense.push_back(p);
        }
    a.ileumMm.resize(std::size_t(std::floor(denseArc.back())) + 1);
    forEachArcSample(denseArc, 1.0, a.ileumMm.size(), [&](std::size_t i, std::size_t d, double w, double) {
        a.ileumMm[i] = dense[d] * (1.0 - w) + dense[d + 1] * w;
    });
    a.ileumRadiusMm = RADIUS_MM;
    a.ileumValveArcMm = double(valve) * a.stepMm;
    // Clear of every other loop of the colon (the cecum round the valve aside), of the spine
    // and of the skin.
    const double wallGap = 2.0 * COLON_WALL_MM + 4.0;
    for (std::size_t s = 0; s < a.ileumMm.size(); ++s) {
        const Vec3d& q = a.ileumMm[s];
        for (std::size_t i = 0; i < n; ++i) {
            const bool nearValve = double(i) * a.stepMm > a.ileumValveArcMm - 120.0 && s < 70;
            if (nearValve) continue;
            const double gap = distance(q, a.centerlineMm[i]) - a.radiusMm[i] - RADIUS_MM;
            if (gap < wallGap)
                throw std::logic_error("phantom anatomy: the ileum comes within " + std::to_string(gap) +
                                       " mm of the colon at colon arc " + std::to_string(i) + ", ileum arc " +
                                       std::to_string(s));
        }
        if (std::hypot(q.x, q.y - SPINE_CENTER_Y_MM) - SPINE_RADIUS_MM - RADIUS_MM < 10.0 ||
            bodySignedDistanceMm(q.x, q.y) > -(RADIUS_MM + COLON_WALL_MM + 10.0))
            throw std::logic_error("phantom anatomy: the ileum runs into the spine or the skin at ileum arc " +
                                   std::to_string(s));
    }
    std::vector<Ellipsoid> pockets;
    for (const Ellipsoid& e : a.gasPockets) {
        bool clear = true;
        for (const Vec3d& q : a.ileumMm)
            clear = clear && e.signedDistanceMm(q) > RADIUS_MM + wallGap;
        if (clear) pockets.push_back(e);
    }
    a.gasPockets = std::move(pockets);
}

} // namespace flyover::phantom
