// The path geometry steps of the centerline (step 4 of centerline.cpp): from one piece's voxel
// path to its smooth centerline.
#include "colon/centerline_path.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

namespace flyover::centerline_path {

Vec3d toVec(const openvdb::Vec3d& v) { return {v[0], v[1], v[2]}; }

/// Arc length at each vertex of a polyline.
std::vector<double> arcLengths(const std::vector<Vec3d>& pts)
{
    std::vector<double> s(pts.size(), 0.0);
    for (std::size_t i = 1; i < pts.size(); ++i) s[i] = s[i - 1] + distance(pts[i], pts[i - 1]);
    return s;
}

/// Position at arc length `t` along the polyline (linear interpolation); `hint` is a vertex
/// index at or before `t` that the caller advances monotonically.
Vec3d pointAt(const std::vector<Vec3d>& pts, const std::vector<double>& s, double t,
              std::size_t& hint)
{
    while (hint + 2 < pts.size() && s[hint + 1] < t) ++hint;
    const double seg = s[hint + 1] - s[hint];
    const double a = seg > 0 ? std::clamp((t - s[hint]) / seg, 0.0, 1.0) : 0.0;
    return pts[hint] * (1.0 - a) + pts[hint + 1] * a;
}

/// Resamples a polyline at n+1 points evenly spaced in arc length (both ends included).
std::vector<Vec3d> resampleEven(const std::vector<Vec3d>& pts, double spacing)
{
    const std::vector<double> s = arcLengths(pts);
    const double total = s.back();
    const std::size_t n = std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(total / spacing)));
    std::vector<Vec3d> out(n + 1);
    std::size_t hint = 0;
    for (std::size_t i = 0; i <= n; ++i) out[i] = pointAt(pts, s, total * double(i) / double(n), hint);
    out.back() = pts.back();
    return out;
}


/// Moves each point of an evenly sampled path onto the ridge of D (the medial axis) within the
/// plane through it perpendicular to the local path direction, by parabolic line searches of
/// D with a one-voxel stencil along two in-plane directions, alternated until neither improves
/// D. The voxel path is quantised to voxel centres and joins the axis at an angle near its ends;
/// centering removes both before smoothing. The total move is limited to half the local depth
/// so that a point never jumps across a fold to another part of the lumen.
std::vector<Vec3d> centerOnRidge(const std::vector<Vec3d>& pts, const openvdb::FloatGrid& grid,
                                 double voxelMm, double spacingMm)
{
    const long n = static_cast<long>(pts.size());
    std::vector<Vec3d> out(pts);
    if (n < 3) return out;
    const long half = std::max(1L, static_cast<long>(std::lround(2.0 * voxelMm / spacingMm)));
    tbb::parallel_for(tbb::blocked_range<long>(0, n, 64), [&](const tbb::blocked_range<long>& r) {
        DepthProbe depthAt(grid);
        for (long i = r.begin(); i != r.end(); ++i) {
            const Vec3d t = normalize(pts[std::min(n - 1, i + half)] - pts[std::max(0L, i - half)]);
            if (length(t) == 0) continue;
            const Vec3d helper = std::abs(t.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
            const Vec3d u1 = normalize(cross(t, helper)), u2 = cross(t, u1);
            const Vec3d p0 = pts[i];
            Vec3d p = p0;
            double dp = depthAt(p);
            const double maxShift = 0.5 * std::max(0.0, dp);
            // One parabolic step along u; returns whether it moved to a deeper point.
            auto search = [&](const Vec3d& u) {
                const double dm = depthAt(p - u * voxelMm), dq = depthAt(p + u * voxelMm);
                const double curvature = dm - 2.0 * dp + dq;
                double step;
                if (curvature < 0) step = std::clamp(0.5 * voxelMm * (dm - dq) / curvature, -voxelMm, voxelMm);
                else if (std::max(dm, dq) > dp) step = dq > dm ? voxelMm : -voxelMm;
                else return false;
                const Vec3d q = p + u * step;
                if (distance(q, p0) > maxShift) return false;
                const double dq2 = depthAt(q);
                if (!(dq2 > dp)) return false;
                p = q;
                dp = dq2;
                return true;
            };
            for (int k = 0; k < 16; ++k) {  // at most 16 voxels of travel
                const bool moved1 = search(u1);
                const bool moved2 = search(u2);
                if (!moved1 && !moved2) break;
            }
            out[i] = p;
        }
    });
    return out;
}

/// Least-squares line p(i) = a + b i through the samples first..last of `pts`.
void fitLine(const std::vector<Vec3d>& pts, long first, long last, Vec3d& a, Vec3d& b)
{
    const double n = double(last - first + 1);
    double si = 0, sii = 0;
    Vec3d sp, sip;
    for (long i = first; i <= last; ++i) {
        si += double(i);
        sii += double(i) * double(i);
        sp += pts[i];
        sip += pts[i] * double(i);
    }
    const double den = n * sii - si * si;
    b = den > 0 ? (sip * n - sp * si) / den : Vec3d{};
    a = (sp - b * si) / n;
}

/// Gaussian smoothing of an evenly spaced polyline (sigma in samples). Beyond each end the
/// polyline is continued by the least-squares line through its last 1.5 sigma of samples (a
/// variant of reflection): a straight end is reproduced exactly, so the ends neither shrink
/// towards the middle nor bend, while the end points themselves are smoothed like the rest
/// (the first voxel of a path is as noisy as any other). A quadratic continuation would follow
/// curved ends too, but it amplifies the staircase noise of the voxel path at the very end.
std::vector<Vec3d> gaussianSmooth(const std::vector<Vec3d>& pts, double sigmaSamples)
{
    const long n = static_cast<long>(pts.size());
    if (!(sigmaSamples > 0.0) || n < 3) return pts;
    const long radius = static_cast<long>(std::ceil(3.0 * sigmaSamples));
    std::vector<double> w(radius + 1);
    double wsum = 0;
    for (long k = 0; k <= radius; ++k) {
        w[k] = std::exp(-0.5 * double(k * k) / (sigmaSamples * sigmaSamples));
        wsum += k == 0 ? w[k] : 2 * w[k];
    }
    const long fitCount = std::clamp(static_cast<long>(std::ceil(1.5 * sigmaSamples)), 2L, n);
    Vec3d headA, headB, tailA, tailB;
    fitLine(pts, 0, fitCount - 1, headA, headB);
    fitLine(pts, n - fitCount, n - 1, tailA, tailB);
    auto at = [&](long i) -> Vec3d {
        if (i < 0) return headA + headB * double(i);
        if (i >= n) return tailA + tailB * double(i);
        return pts[i];
    };
    std::vector<Vec3d> out(pts.size());
    tbb::parallel_for(tbb::blocked_range<long>(0, n, 256), [&](const tbb::blocked_range<long>& r) {
        for (long i = r.begin(); i != r.end(); ++i) {
            Vec3d acc = pts[i] * w[0];
            for (long k = 1; k <= radius; ++k) acc += (at(i - k) + at(i + k)) * w[k];
            out[i] = acc / wsum;
        }
    });
    return out;
}


/// Distance from `origin` (inside the lumen) along the unit vector `dir` to the first zero
/// crossing of the sdf; -1 when there is none within maxMm. Sphere tracing: a step of 90% of
/// |sdf| never reaches the wall, however thin (a fold), because |sdf| is at most the distance
/// to the nearest wall; a floor of a quarter voxel bounds the step count near the wall. The
/// crossing is then located by four regula falsi steps in the bracketing interval.
double rayToWall(SdfProbe& sdf, const Vec3d& origin, const Vec3d& dir, double maxMm, double voxelMm)
{
    double tIn = 0.0, sIn = sdf(origin);
    if (!(sIn < 0.0)) return 0.0;
    const double minStep = 0.25 * voxelMm;
    while (tIn < maxMm) {
        const double t = tIn + std::max(-0.9 * sIn, minStep);
        const double s = sdf(origin + dir * t);
        if (s >= 0.0) {
            double a = tIn, fa = sIn, b = t, fb = s;
            for (int k = 0; k < 4; ++k) {
                const double m = a + (b - a) * fa / (fa - fb);
                const double fm = sdf(origin + dir * m);
                if (fm < 0.0) {
                    a = m;
                    fa = fm;
                } else {
                    b = m;
                    fb = fm;
                }
            }
            return a + (b - a) * fa / (fa - fb);
        }
        tIn = t;
        sIn = s;
    }
    return -1.0;
}

/// The lumen's cross-section in the plane through p perpendicular to the unit vector t, as
/// the star-shaped polygon of the wall hits of RAYS rays from p.
struct Section {
    Vec3d centroidMm;
    double areaMm2 = 0;
    bool ok = false;   ///< every ray hit the wall within reach and the centroid is in the lumen
};

constexpr int SECTION_RAYS = 32;

Section crossSection(SdfProbe& sdf, const Vec3d& p, const Vec3d& t, double maxRayMm, double voxelMm)
{
    const Vec3d helper = std::abs(t.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
    const Vec3d u1 = normalize(cross(t, helper)), u2 = cross(t, u1);
    std::array<Vec3d, SECTION_RAYS> hit;
    constexpr double TWO_PI = 6.283185307179586476925;
    for (int k = 0; k < SECTION_RAYS; ++k) {
        const double a = TWO_PI * k / SECTION_RAYS;
        const Vec3d dir = u1 * std::cos(a) + u2 * std::sin(a);
        const double r = rayToWall(sdf, p, dir, maxRayMm, voxelMm);
        if (!(r > 0.0)) return {};
        hit[k] = dir * r;  // relative to p
    }
    // Fan of triangles (p, hit k, hit k+1): area-weighted centroids.
    Section sec;
    Vec3d moment;
    for (int k = 0; k < SECTION_RAYS; ++k) {
        const Vec3d& a = hit[k];
        const Vec3d& b = hit[(k + 1) % SECTION_RAYS];
        const double area = 0.5 * length(cross(a, b));
        sec.areaMm2 += area;
        moment += (a + b) * (area / 3.0);
    }
    if (!(sec.areaMm2 > 0.0)) return {};
    sec.centroidMm = p + moment / sec.areaMm2;
    sec.ok = sdf(sec.centroidMm) < 0.0;
    return sec;
}

/// Moves an evenly sampled path (spacing spacingMm) to the centroids of the lumen's cross-
/// sections perpendicular to it, taken every sectionStride samples. A haustral fold or a large
/// polyp cuts into the sections within its thickness and pulls their centroids (and the ridge
/// of D, over a whole lumen radius either side) off the axis of the lumen; such sections are
/// recognised by an area below 85% of the median over the neighbouring SECTION_WINDOW_MM
/// either side (a fold takes a quarter to a third of the section, taper and bends change the
/// area by a few per cent over that window) and skipped: their displacement, like that of
/// sections whose rays do not all reach the wall (the end caps, an oblique cut at a tight
/// bend), is interpolated linearly from the nearest kept sections.
std::vector<Vec3d> centerOnSections(const std::vector<Vec3d>& pts, const openvdb::FloatGrid& grid,
                                    double voxelMm, double spacingMm, long* firstKept = nullptr,
                                    long* lastKept = nullptr)
{
    const long n = static_cast<long>(pts.size());
    if (n < 3) return pts;
    constexpr double SECTION_WINDOW_MM = 20.0;
    const double MIN_AREA_FRACTION = 0.9;
    const double GROW_MM = 3.0;
    const double SHIFT_FRACTION = 1.0;
    const double TANGENT_SIGMA_MM = 8.0;
    const long stride = std::max(1L, static_cast<long>(std::lround(std::min(voxelMm, 1.0) / spacingMm)));
    std::vector<long> at;
    for (long i = 0; i < n; i += stride) at.push_back(i);
    if (at.back() != n - 1) at.push_back(n - 1);
    const long m = static_cast<long>(at.size());

    // Section normals from the path smoothed over two voxels (the sampled path has
    // voxel-scale wiggles that would tilt single sections).
    const std::vector<Vec3d> smooth = gaussianSmooth(pts, std::max(2.0 * voxelMm, TANGENT_SIGMA_MM) / spacingMm);
    const long half = std::max(1L, static_cast<long>(std::lround(voxelMm / spacingMm)));

    std::vector<Section> sections(static_cast<std::size_t>(m));
    tbb::parallel_for(tbb::blocked_range<long>(0, m, 16), [&](const tbb::blocked_range<long>& r) {
        SdfProbe sdf(grid);
        for (long j = r.begin(); j != r.end(); ++j) {
            const long i = at[j];
            const Vec3d t = normalize(smooth[std::min(n - 1, i + half)] - smooth[std::max(0L, i - half)]);
            if (length(t) == 0) continue;
            const double depth = std::max(-sdf(pts[i]), voxelMm);
            Section s = crossSection(sdf, pts[i], t, 3.0 * depth, voxelMm);
            // A centroid farther than the local depth from the point is not the same stretch of
            // lumen (the section reaches round a tight bend or into a pocket).
            if (s.ok && distance(s.centroidMm, pts[i]) > SHIFT_FRACTION * depth) s.ok = false;
            sections[j] = s;
        }
    });

    const long window = std::max(2L, static_cast<long>(std::lround(SECTION_WINDOW_MM / (stride * spacingMm))));
    std::vector<char> keep(static_cast<std::size_t>(m), 0);
    std::vector<double> areas;
    for (long j = 0; j < m; ++j) {
        if (!sections[j].ok) continue;
        areas.clear();
        for (long k = std::max(0L, j - window); k <= std::min(m - 1, j + window); ++k)
            if (sections[k].ok) areas.push_back(sections[k].areaMm2);
        auto mid = areas.begin() + static_cast<long>(areas.size() / 2);
        std::nth_element(areas.begin(), mid, areas.end());
        keep[j] = sections[j].areaMm2 >= MIN_AREA_FRACTION * *mid;
    }
    {
        // Sections next to a skipped one are tilted through the same fold or polyp by the
        // path's own deviation there: skip them too.
        const long grow = std::max(1L, static_cast<long>(std::lround(GROW_MM / (stride * spacingMm))));
        std::vector<char> grown(keep);
        for (long j = 0; j < m; ++j)
            if (!keep[j] && sections[j].ok)
                for (long k = std::max(0L, j - grow); k <= std::min(m - 1, j + grow); ++k) grown[k] = 0;
        keep.swap(grown);
    }

    {
        // The centroids of a tube's sections lie on a smooth curve. Where the lumen is no tube
        // (a pouch, two limbs merged in a coarse mask) neighbouring sections cut different
        // parts of it and their centroids jump: skip a section whose centroid lies more than
        // half a voxel off the line through the kept centroids within two voxels either side.
        const long reach = std::max(2L, static_cast<long>(std::lround(2.0 * voxelMm / (stride * spacingMm))));
        const double tolerance = 0.5 * voxelMm;
        std::vector<char> smoothOk(keep);
        for (long j = 0; j < m; ++j) {
            if (!keep[j]) continue;
            double n = 0, st = 0, stt = 0;
            Vec3d sc, stc;
            for (long k = std::max(0L, j - reach); k <= std::min(m - 1, j + reach); ++k) {
                if (k == j || !keep[k]) continue;
                const double t = double(k - j);
                n += 1;
                st += t;
                stt += t * t;
                sc += sections[k].centroidMm;
                stc += sections[k].centroidMm * t;
            }
            const double den = n * stt - st * st;
            if (n < 2 || !(den > 0)) continue;
            const Vec3d slope = (stc * n - sc * st) / den;
            const Vec3d at0 = (sc - slope * st) / n;  // the fitted line at t = 0
            if (distance(at0, sections[j].centroidMm) > tolerance) smoothOk[j] = 0;
        }
        keep.swap(smoothOk);
    }

    // Skipped sections get positions from the kept centroids around them: a cubic Hermite
    // curve through the two kept neighbours, with tangents from kept centroids a few mm
    // further on (Catmull-Rom), so a skipped fold neither keeps the path's own deviation there
    // nor cuts a bend. Gaps longer than SPLINE_GAP_MM (the end caps, long oblique stretches)
    // instead get the displacement interpolated linearly; before the first and after the last
    // kept section the displacement is held.
    constexpr double SPLINE_GAP_MM = 25.0;
    constexpr double TANGENT_BASE_MM = 5.0;
    std::vector<long> kept;
    for (long j = 0; j < m; ++j)
        if (keep[j]) kept.push_back(j);
    if (kept.empty()) return pts;
    if (firstKept) *firstKept = at[kept.front()];
    if (lastKept) *lastKept = at[kept.back()];
    std::vector<Vec3d> shift(static_cast<std::size_t>(m));
    for (long j : kept) shift[j] = sections[j].centroidMm - pts[at[j]];
    for (long k = 0; k < kept.front(); ++k) shift[k] = shift[kept.front()];
    for (long k = kept.back() + 1; k < m; ++k) shift[k] = shift[kept.back()];
    const long baseSamples = std::max(1L, static_cast<long>(std::lround(TANGENT_BASE_MM / spacingMm)));
    auto centroidTangent = [&](std::size_t q) {  // d centroid / d sample index at kept[q]
        std::size_t lo = q, hi = q;
        while (lo > 0 && at[kept[q]] - at[kept[lo]] < baseSamples) --lo;
        while (hi + 1 < kept.size() && at[kept[hi]] - at[kept[q]] < baseSamples) ++hi;
        if (hi == lo) return Vec3d{};
        return (sections[kept[hi]].centroidMm - sections[kept[lo]].centroidMm) /
               double(at[kept[hi]] - at[kept[lo]]);
    };
    for (std::size_t q = 0; q + 1 < kept.size(); ++q) {
        const long j0 = kept[q], j1 = kept[q + 1];
        if (j1 - j0 < 2) continue;
        const double h = double(at[j1] - at[j0]);
        if (h * spacingMm > SPLINE_GAP_MM) {
            for (long k = j0 + 1; k < j1; ++k) {
                const double a = double(at[k] - at[j0]) / h;
                shift[k] = shift[j0] * (1.0 - a) + shift[j1] * a;
            }
            continue;
        }
        const Vec3d c0 = sections[j0].centroidMm, c1 = sections[j1].centroidMm;
        const Vec3d m0 = centroidTangent(q) * h, m1 = centroidTangent(q + 1) * h;
        for (long k = j0 + 1; k < j1; ++k) {
            const double t = double(at[k] - at[j0]) / h, t2 = t * t, t3 = t2 * t;
            const Vec3d pos = c0 * (2 * t3 - 3 * t2 + 1) + m0 * (t3 - 2 * t2 + t) +
                              c1 * (-2 * t3 + 3 * t2) + m1 * (t3 - t2);
            shift[k] = pos - pts[at[k]];
        }
    }

    std::vector<Vec3d> out(pts.size());
    for (long j = 0; j + 1 < m; ++j)
        for (long i = at[j]; i <= at[j + 1]; ++i) {
            const double a = double(i - at[j]) / double(at[j + 1] - at[j]);
            out[i] = pts[i] + shift[j] * (1.0 - a) + shift[j + 1] * a;
        }
    return out;
}

/// Ends, part 1. The geodesic farthest voxels lie on the wall of the blind ends, generally not
/// at the pole of the end cap (the voxel metric is anisotropic), and within a cap D has no
/// ridge: the cheapest path runs straight from that wall voxel to where the medial axis
/// begins, at an angle to the lumen's axis. Along that approach D grows as fast as the path
/// advances (dD/ds ~ 1), while along the medial axis it changes slowly (taper and folds:
/// |dD/ds| well below 1). So each end loses its leading run on which D rises by more than
/// half the distance travelled over the next 1.5 voxels.
std::vector<Vec3d> trimEnds(const std::vector<Vec3d>& fine, DepthProbe& depthAt, double voxelMm)
{
    std::vector<double> depth(fine.size());
    for (std::size_t i = 0; i < fine.size(); ++i) depth[i] = depthAt(fine[i]);
    const std::vector<double> s = arcLengths(fine);
    const double windowMm = 1.5 * voxelMm;
    const double slope = 0.5;
    std::size_t first = 0, last = fine.size() - 1;
    for (std::size_t j = 0; first < last; ++first) {
        while (j < last && s[j] - s[first] < windowMm) ++j;
        if (depth[j] - depth[first] < slope * (s[j] - s[first])) break;
    }
    for (std::size_t j = last; last > first; --last) {
        while (j > first && s[last] - s[j] < windowMm) --j;
        if (depth[j] - depth[last] < slope * (s[last] - s[j])) break;
    }
    // Never trim a path away completely: keep its middle if nothing qualifies.
    if (last <= first) first = last = fine.size() / 2;
    return std::vector<Vec3d>(fine.begin() + first, fine.begin() + last + 1);
}

/// Smoothing along arc length of an evenly sampled path. A Gaussian alone pulls a bend of
/// radius R inwards by about sigma^2 / (2 R) (0.8 mm for sigma 4 mm on a 10 mm flexure), so the
/// residual is smoothed once more and added back ("twicing", the filter 2G - G^2): the bias
/// drops to fourth order in sigma while voxel-scale staircase noise is still removed.
std::vector<Vec3d> smoothTwiced(const std::vector<Vec3d>& fine, double sigmaMm)
{
    if (fine.size() < 3 || !(sigmaMm > 0)) return fine;
    const double spacing = arcLengths(fine).back() / double(fine.size() - 1);
    if (!(spacing > 0)) return fine;
    const double sigma = sigmaMm / spacing;
    const std::vector<Vec3d> once = gaussianSmooth(fine, sigma);
    std::vector<Vec3d> residual(fine.size());
    for (std::size_t i = 0; i < fine.size(); ++i) residual[i] = fine[i] - once[i];
    const std::vector<Vec3d> back = gaussianSmooth(residual, sigma);
    std::vector<Vec3d> out(fine.size());
    for (std::size_t i = 0; i < fine.size(); ++i) out[i] = once[i] + back[i];
    return out;
}

/// Turning angle (degrees) at every sample of an evenly sampled path between the chords of
/// `chordSamples` samples before and after it; 0 where either chord is cut by an end.
std::vector<double> chordTurnsDeg(const std::vector<Vec3d>& pts, long chordSamples)
{
    const long n = static_cast<long>(pts.size());
    std::vector<double> turn(pts.size(), 0.0);
    for (long i = chordSamples; i + chordSamples < n; ++i) {
        const Vec3d a = normalize(pts[i] - pts[i - chordSamples]), b = normalize(pts[i + chordSamples] - pts[i]);
        if (length(a) == 0 || length(b) == 0) continue;
        turn[i] = std::acos(std::clamp(dot(a, b), -1.0, 1.0)) * 180.0 / 3.14159265358979323846;
    }
    return turn;
}

/// Kinks: where the smoothed path still turns more than MAX_TURN_DEG_PER_MM between consecutive
/// 1 mm chords (the section centroids jumping between the lobes of an irregular lumen, a seam
/// where the ridge was kept: a wiggle of a few mm that the cameras would follow with a spin),
/// the path is smoothed again there, with a Gaussian that widens each round (2 mm, then by
/// sqrt 2 up to 16 mm), blended in over a window round each kink and out over two more sigma.
/// A point moves at most half its depth (the ball of lumen round it: never across a wall into
/// a touching loop), and one that would come closer to the wall than min(MIN_WALL_MM, half its
/// depth before) is moved back towards where it was until it is not (a tight bend in a narrow lumen
/// keeps its corner). The bound leaves a margin under 30 degrees per 1 mm step and 15 degrees of camera
/// normal (the rotation-minimising normal turns no more than the tangent does). `fine` is
/// evenly sampled every fineMm; so is the result.
std::vector<Vec3d> removeKinks(const std::vector<Vec3d>& fine, const openvdb::FloatGrid& grid, double fineMm)
{
    constexpr double MAX_TURN_DEG_PER_MM = 12.0;
    constexpr double MIN_WALL_MM = 1.0;
    constexpr int ROUNDS = 7;
    const long chord = std::max(1L, std::lround(1.0 / fineMm));
    std::vector<Vec3d> pts = fine;
    // The depth of the path as it came, by arc fraction: the bounds below hold against it, not
    // against the previous round's (which would let each round take another half).
    std::vector<double> depthBefore(fine.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, fine.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
        DepthProbe depth(grid);
        for (std::size_t i = r.begin(); i != r.end(); ++i) depthBefore[i] = depth(fine[i]);
    });
    auto depthBeforeAt = [&](long i, long n) {
        const long j = n > 1 ? std::lround(double(i) * double(fine.size() - 1) / double(n - 1)) : 0;
        return depthBefore[std::size_t(std::clamp(j, 0L, static_cast<long>(fine.size()) - 1))];
    };
    for (int round = 0; round < ROUNDS && static_cast<long>(pts.size()) > 4 * chord; ++round) {
        const std::vector<double> turn = chordTurnsDeg(pts, chord);
        const long n = static_cast<long>(pts.size());
        const double sigmaMm = 2.0 * std::pow(std::sqrt(2.0), round);
        const long inner = static_cast<long>(std::ceil(2.0 * sigmaMm / fineMm)), outer = 2 * inner;
        // Blend weight: 1 within `inner` samples of a kink, falling smoothly to 0 over `outer` more.
        std::vector<double> w(pts.size(), 0.0);
        bool any = false;
        for (long i = 0; i < n; ++i) {
            if (!(turn[i] > MAX_TURN_DEG_PER_MM)) continue;
            any = true;
            for (long j = std::max(0L, i - inner - outer); j <= std::min(n - 1, i + inner + outer); ++j) {
                const long d = std::abs(j - i);
                const double x = d <= inner ? 1.0 : 1.0 - double(d - inner) / double(outer);
                w[j] = std::max(w[j], x * x * (3.0 - 2.0 * x));
            }
        }
        if (!any) break;
        const std::vector<Vec3d> smooth = gaussianSmooth(pts, sigmaMm / fineMm);
        std::vector<Vec3d> out(pts.size());
        tbb::parallel_for(tbb::blocked_range<long>(0, n, 256), [&](const tbb::blocked_range<long>& r) {
            DepthProbe depth(grid);
            for (long i = r.begin(); i != r.end(); ++i) {
                out[i] = pts[i];
                if (w[i] <= 0.0) continue;
                const double here = std::max(0.0, depthBeforeAt(i, n));
                const double floorMm = std::min(MIN_WALL_MM, 0.5 * here);
                // A move stays within the lumen ball round the point (half its depth), so it
                // never crosses a wall into another loop however wide the Gaussian.
                const double maxMoveMm = 0.5 * here;
                double t = w[i];
                for (int k = 0; k < 6 && t > 0.0; ++k, t *= 0.5) {
                    Vec3d move = (smooth[i] - pts[i]) * t;
                    const double len = length(move);
                    if (len > maxMoveMm) move = move * (maxMoveMm / len);
                    const Vec3d q = pts[i] + move;
                    if (depth(q) >= floorMm) {
                        out[i] = q;
                        break;
                    }
                }
            }
        });
        pts = resampleEven(out, fineMm);
    }
    return pts;
}

/// Ends, part 2: continues the path straight along its end tangent into the blind end until
/// D falls to 60% of its value at the end. The path stops about one radius short of the cap
/// wall (where sections stop being whole); the extension lets the end cameras look into the
/// cap while keeping a reasonable radius there. Within the cap the direction is extrapolated,
/// so its error grows with the extension's length: 60% rather than half keeps the end within
/// a voxel of the axis' straight continuation on the test shapes. Extends path.back().
void extendEnd(std::vector<Vec3d>& path, DepthProbe& depthAt, double fineMm)
{
    const Vec3d end = path.back();
    const double endDepth = depthAt(end);
    if (!(endDepth > 0) || path.size() < 2) return;
    // End tangent: least-squares line through the last radius of path.
    const std::vector<double> s = arcLengths(path);
    const double tangentMm = std::min(endDepth, 0.5 * s.back());
    const long lastIndex = static_cast<long>(path.size()) - 1;
    long k = lastIndex;
    while (k > 0 && s.back() - s[k] < tangentMm) --k;
    Vec3d a, b;
    fitLine(path, std::min(k, lastIndex - 1), lastIndex, a, b);
    const Vec3d dir = normalize(b);
    if (length(dir) == 0) return;
    for (double x = fineMm; x <= 2.0 * endDepth; x += fineMm) {
        const Vec3d q = end + dir * x;
        if (depthAt(q) < 0.6 * endDepth) break;
        path.push_back(q);
    }
}

/// Where the section-centred path left the deep lumen, the ridge is kept. The centroids of a
/// tube's sections lie on its axis, where D is about the lumen radius (a fold or a polyp moves
/// them by a fraction of it). Where the sections overlap, as in a bend tighter than the lumen
/// radius (a flexure folded back on itself: the sections of its inner side cross each other
/// and reach into the other limb), or cut lengthwise through a pouch, their centroids fall
/// towards the inner wall, and each round of centring, taking its section planes from the path
/// the round before moved, moves the path further, until it hugs the inner wall or the tip of
/// the fold between the limbs (gca-colon-00020: 16 mm off the reference path at D 1.6 mm, where
/// the ridge kept 17 mm of lumen round the bend). So a point of the centred path less than
/// SHALLOW_FRACTION as deep as the ridge point nearest to it, and moved off it by more than
/// OFFSET_FRACTION of that depth (a fold moves the centroid less), marks a stretch that is no
/// tube's section centre; where the ridge itself has no lumen to speak of (under
/// MIN_RIDGE_VOXELS deep: a neck or a thread of lumen, where it is no better a guide) nothing is
/// replaced. The stretch, widened on either hand until the centred path is back within
/// SEAM_FRACTION of the ridge's depth of it, is replaced by the ridge between the matching
/// points (the smoothing that follows removes the small steps at the seams). Returns `centred`
/// itself where no point is that shallow.
std::vector<Vec3d> keepRidgeWhereShallow(const std::vector<Vec3d>& centred, const std::vector<Vec3d>& ridge,
                                         const openvdb::FloatGrid& grid, double voxelMm, double fineMm)
{
    constexpr double SHALLOW_FRACTION = 0.5;
    constexpr double OFFSET_FRACTION = 0.5;
    constexpr double MIN_RIDGE_VOXELS = 2.0;
    constexpr double SEAM_FRACTION = 0.15;
    constexpr double MATCH_WINDOW_MM = 150.0;  // how far apart matching points may lie along the paths
    const long n = static_cast<long>(centred.size()), nr = static_cast<long>(ridge.size());
    if (n < 3 || nr < 3) return centred;
    std::vector<double> dc(centred.size()), dr(ridge.size());
    tbb::parallel_for(tbb::blocked_range<long>(0, std::max(n, nr), 256), [&](const tbb::blocked_range<long>& r) {
        DepthProbe depthAt(grid);
        for (long i = r.begin(); i != r.end(); ++i) {
            if (i < n) dc[i] = depthAt(centred[i]);
            if (i < nr) dr[i] = depthAt(ridge[i]);
        }
    });
    // Nearest ridge point of each centred point, within a window around the arc-proportional
    // position (both paths run between the same ends).
    const long window = static_cast<long>(MATCH_WINDOW_MM / fineMm);
    std::vector<long> match(centred.size());
    tbb::parallel_for(tbb::blocked_range<long>(0, n, 256), [&](const tbb::blocked_range<long>& r) {
        for (long i = r.begin(); i != r.end(); ++i) {
            const long centre = static_cast<long>(double(i) * double(nr - 1) / double(n - 1));
            long best = centre;
            double bestD = std::numeric_limits<double>::infinity();
            for (long j = std::max(0L, centre - window); j <= std::min(nr - 1, centre + window); ++j) {
                const double d = distance(centred[i], ridge[j]);
                if (d < bestD) {
                    bestD = d;
                    best = j;
                }
            }
            match[i] = best;
        }
    });
    auto shallow = [&](long i) {
        const double ridgeDepth = dr[match[i]];
        return ridgeDepth >= MIN_RIDGE_VOXELS * voxelMm && dc[i] < SHALLOW_FRACTION * ridgeDepth &&
               distance(centred[i], ridge[match[i]]) > OFFSET_FRACTION * ridgeDepth;
    };
    auto onRidge = [&](long i) { return distance(centred[i], ridge[match[i]]) <= SEAM_FRACTION * dr[match[i]]; };
    std::vector<Vec3d> out;
    long copied = 0;  // centred[copied..] not yet handled
    int count = 0;
    for (long i = 0; i < n; ++i) {
        if (!shallow(i)) continue;
        long a = i, b = i;
        while (a > copied && !onRidge(a)) --a;
        while (b + 1 < n && (shallow(b + 1) || !onRidge(b))) ++b;
        out.insert(out.end(), centred.begin() + copied, centred.begin() + a);
        if (match[a] <= match[b]) out.insert(out.end(), ridge.begin() + match[a], ridge.begin() + match[b] + 1);
        copied = b + 1;
        i = b;
        ++count;
    }
    if (count == 0) return centred;
    out.insert(out.end(), centred.begin() + copied, centred.end());
    return resampleEven(out, fineMm);
}

/// Rounds of centring on sections: each starts from the previous one's path and section
/// planes; the third changes the path by well under a tenth of a voxel on the phantoms.
constexpr int SECTION_ITERATIONS = 3;

/// From the voxel path of one piece to its smooth centerline, sampled every fineMm.
std::vector<Vec3d> refinePath(const std::vector<Vec3d>& raw, const openvdb::FloatGrid& grid,
                              double voxelMm, double fineMm, const CenterlineParams& params)
{
    if (raw.size() < 2) return raw;
    DepthProbe depthAt(grid);  // serial uses below
    std::vector<Vec3d> fine = trimEnds(resampleEven(raw, fineMm), depthAt, voxelMm);
    if (fine.size() >= 3) {
        const double spacing = arcLengths(fine).back() / double(fine.size() - 1);
        if (spacing > 0) fine = resampleEven(centerOnRidge(fine, grid, voxelMm, spacing), fineMm);
    }
    const std::vector<Vec3d> ridge = fine;
    if (params.centerSections)
        for (int iteration = 0; iteration < SECTION_ITERATIONS && fine.size() >= 3; ++iteration) {
            const double spacing = arcLengths(fine).back() / double(fine.size() - 1);
            if (!(spacing > 0)) break;
            long first = 0, last = -1;
            std::vector<Vec3d> moved = centerOnSections(fine, grid, voxelMm, spacing, &first, &last);
            // Beyond the outermost whole sections (the end caps, the approach of the voxel path
            // from the cap wall) the path is not centred: cut it there; the ends are continued
            // straight along the centred path below.
            if (iteration + 1 == SECTION_ITERATIONS && last > first) {
                // At most two lumen radii: a longer stretch of broken sections at an end is a
                // lumen that is no tube there, not an end cap, and it is kept.
                const long n = static_cast<long>(moved.size());
                first = std::min(first, static_cast<long>(2.0 * depthAt(moved[first]) / spacing));
                last = std::max(last, n - 1 - static_cast<long>(2.0 * depthAt(moved[last]) / spacing));
                if (last > first) moved = std::vector<Vec3d>(moved.begin() + first, moved.begin() + last + 1);
            }
            fine = resampleEven(moved, fineMm);
        }
    if (params.centerSections) fine = keepRidgeWhereShallow(fine, ridge, grid, voxelMm, fineMm);
    fine = removeKinks(smoothTwiced(fine, params.smoothingMm), grid, fineMm);
    extendEnd(fine, depthAt, fineMm);
    std::reverse(fine.begin(), fine.end());
    extendEnd(fine, depthAt, fineMm);
    std::reverse(fine.begin(), fine.end());
    return fine;
}

/// Outward unit tangent at the back end of a path: the chord over its last few millimetres.
Vec3d backOutward(const std::vector<Vec3d>& path, double voxelMm)
{
    if (path.size() < 2) return {0, 0, 1};
    const std::vector<double> s = arcLengths(path);
    const double reach = std::min(std::max(3.0 * voxelMm, 5.0), 0.5 * s.back());
    std::size_t k = path.size() - 1;
    while (k > 0 && s.back() - s[k] < reach) --k;
    const Vec3d d = normalize(path.back() - path[k]);
    return length(d) > 0 ? d : Vec3d{0, 0, 1};
}

Vec3d frontOutward(const std::vector<Vec3d>& path, double voxelMm)
{
    std::vector<Vec3d> r(path.rbegin(), path.rend());
    return backOutward(r, voxelMm);
}

/// Stretches of the path closer to the wall than nearWallMm outside bridges.
std::vector<CenterlineNearWall> nearWallStretches(const Centerline& cl, const CenterlineParams& params)
{
    std::vector<CenterlineNearWall> nearWall;
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        const CenterlinePoint& p = cl.points[i];
        if (p.bridged || !(p.radiusMm < params.nearWallMm)) continue;
        const double arc = double(i) * params.stepMm;
        if (!nearWall.empty() && nearWall.back().toArcMm + 1.5 * params.stepMm >= arc) {
            CenterlineNearWall& w = nearWall.back();
            w.toArcMm = arc;
            if (p.radiusMm < w.minRadiusMm) {
                w.minRadiusMm = p.radiusMm;
                w.positionMm = p.positionMm;
            }
        } else {
            nearWall.push_back({arc, arc, p.radiusMm, p.positionMm});
        }
    }
    return nearWall;
}

/// The turns between consecutive steps and the normal's steps, into the report.
void reportTurns(const Centerline& cl, CenterlineReport& report)
{
    auto degrees = [](const Vec3d& a, const Vec3d& b) {
        const double la = length(a), lb = length(b);
        if (la == 0 || lb == 0) return 0.0;
        return std::acos(std::clamp(dot(a, b) / (la * lb), -1.0, 1.0)) * 180.0 / 3.14159265358979323846;
    };
    const auto& cp = cl.points;
    for (std::size_t i = 1; i < cp.size(); ++i) {
        if (i + 1 < cp.size()) {
            const double t = degrees(cp[i].positionMm - cp[i - 1].positionMm, cp[i + 1].positionMm - cp[i].positionMm);
            report.maxTurnDeg = std::max(report.maxTurnDeg, t);
            report.turnsOver30 += t > 30.0;
        }
        const double nrm = degrees(cp[i - 1].normal, cp[i].normal);
        report.maxNormalStepDeg = std::max(report.maxNormalStepDeg, nrm);
        report.normalStepsOver15 += nrm > 15.0;
    }
}

} // namespace flyover::centerline_path
