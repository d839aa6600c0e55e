/// @file phantom_anatomy_detail.h
/// @brief What the phantom's anatomy (phantom_anatomy.cpp) shares with its contacts
///        (phantom_contacts.cpp) and variants (phantom_variants.cpp): the seeded draws, the
///        spline, the arc-length walk and a few steps of the build. Internal to colon/.
#pragma once

#include "colon/phantom_anatomy.h"
#include "volume/vec3.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace flyover::phantom::detail {

/// Arc clearance (mm) of polyps, folds and collapsed stretches from the loops at a contact.
inline constexpr double POLYP_CONTACT_CLEARANCE_MM = 30.0;

inline double uniform01(std::mt19937_64& rng) { return double(rng() >> 11) * 0x1.0p-53; }
inline double uniform(std::mt19937_64& rng, double lo, double hi) { return lo + (hi - lo) * uniform01(rng); }
inline double standardNormal(std::mt19937_64& rng)
{
    const double u1 = (double(rng() >> 11) + 0.5) * 0x1.0p-53;
    const double u2 = uniform01(rng);
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * PI * u2);
}

/// Interpolating C2 cubic spline through points, parameterised by chord length, with
/// natural ends: curvature is continuous, so it does not peak at the control points.
class ChordCubicSpline {
public:
    explicit ChordCubicSpline(const std::vector<Vec3d>& points) : mPoints(points)
    {
        const std::size_t n = points.size();
        mKnots.assign(n, 0.0);
        for (std::size_t i = 1; i < n; ++i)
            mKnots[i] = mKnots[i - 1] + distance(points[i - 1], points[i]);
        // Second derivatives M from the tridiagonal system, natural ends (M = 0).
        mSecond.assign(n, Vec3d{});
        std::vector<double> diag(n, 1.0), upper(n, 0.0);
        std::vector<Vec3d> rhs(n, Vec3d{});
        for (std::size_t i = 1; i + 1 < n; ++i) {
            const double h0 = mKnots[i] - mKnots[i - 1], h1 = mKnots[i + 1] - mKnots[i];
            diag[i] = (h0 + h1) / 3.0;
            upper[i] = h1 / 6.0;
            rhs[i] = (points[i + 1] - points[i]) / h1 - (points[i] - points[i - 1]) / h0;
            // Forward elimination with the row above (lower coefficient h0 / 6).
            const double lower = h0 / 6.0;
            const double m = lower / diag[i - 1];
            diag[i] -= m * upper[i - 1];
            rhs[i] -= rhs[i - 1] * m;
        }
        for (std::size_t i = n - 1; i-- > 1;)
            mSecond[i] = (rhs[i] - mSecond[i + 1] * upper[i]) / diag[i];
    }

    /// Point on span [i, i+1] at fraction u in [0, 1] of its parameter interval.
    Vec3d at(std::size_t i, double u) const
    {
        const double h = mKnots[i + 1] - mKnots[i];
        const double v = 1.0 - u;
        return mPoints[i] * v + mPoints[i + 1] * u +
               (mSecond[i] * (v * v * v - v) + mSecond[i + 1] * (u * u * u - u)) * (h * h / 6.0);
    }

private:
    std::vector<Vec3d> mPoints;
    std::vector<double> mKnots;
    std::vector<Vec3d> mSecond;
};

inline double smoothstep(double u) { return u * u * (3.0 - 2.0 * u); }

/// Walks the samples s = i * stepMm (i < count) of a polyline whose cumulative arc lengths are
/// `arc` (at least two points): f(i, d, w, s) with s between points d and d + 1 at fraction w.
template <class F>
void forEachArcSample(const std::vector<double>& arc, double stepMm, std::size_t count, F&& f)
{
    std::size_t d = 0;
    for (std::size_t i = 0; i < count; ++i) {
        const double s = double(i) * stepMm;
        while (d + 2 < arc.size() && arc[d + 1] < s)
            ++d;
        const double len = arc[d + 1] - arc[d];
        const double w = len > 0 ? std::clamp((s - arc[d]) / len, 0.0, 1.0) : 0.0;
        f(i, d, w, s);
    }
}

/// Tangents by central differences; normal/binormal by the rotation-minimising frame.
void buildFrames(PhantomAnatomy& a);
/// The first centerline sample of a named colon segment. @throw std::logic_error
std::size_t firstIndexOf(const PhantomAnatomy& a, const std::string& name);
/// The invariants later tests rely on, as text (empty: all hold).
std::string anatomyProblems(const PhantomAnatomy& a);
/// Nearest centerline sample of an arc length, clamped to the curve.
std::size_t sampleAt(const PhantomAnatomy& a, double arcMm);
/// The `touching` variant: `count` contacts (phantom_contacts.cpp).
void addContacts(PhantomAnatomy& a, int count, uint64_t seed, const Vec3d& voxelMm);

} // namespace flyover::phantom::detail
