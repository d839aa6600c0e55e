#include "colon/phantom_anatomy.h"
#include "colon/phantom_anatomy_detail.h"

#include "volume/error.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

namespace flyover::phantom {

using namespace detail;

namespace {


/// Colon control points, rectum -> cecum. `segment` names the span that starts at the
/// point (the last point starts none). Radii are the lumen radius at the point.
struct ControlPoint {
    Vec3d positionMm;
    double radiusMm;
    const char* segment;
};

// clang-format off
const ControlPoint COLON_CONTROL_POINTS[] = {
    // Rectum, rising in front of the sacrum, then bending forwards (rectosigmoid).
    {{   0.0,   2.0, -150.0}, 23, "rectum"},
    {{   0.0,   0.0, -122.0}, 24, "rectum"},
    {{   0.0,   0.0,  -92.0}, 21, "rectum"},
    {{   2.7,  -5.6,  -71.0}, 19, "rectum"},
    {{   5.3, -21.0,  -55.6}, 17, "sigmoid"},
    {{   8.0, -42.0,  -50.0}, 16, "sigmoid"},
    {{  10.7, -63.0,  -55.6}, 15, "sigmoid"},
    {{  13.3, -76.5,  -71.0}, 14, "sigmoid"},
    {{  16.0, -81.0,  -92.0}, 14, "sigmoid"},
    // Sigmoid: down into the pelvis, a loop up and over to the left, down again.
    {{  16.0, -79.0, -112.0}, 13, "sigmoid"},
    {{  20.0, -79.0, -127.0}, 13, "sigmoid"},
    {{  31.0, -79.0, -138.0}, 13, "sigmoid"},
    {{  46.0, -79.0, -142.0}, 13, "sigmoid"},
    {{  61.0, -79.0, -138.0}, 13, "sigmoid"},
    {{  72.0, -79.0, -127.0}, 13, "sigmoid"},
    {{  76.0, -79.0, -112.0}, 13, "sigmoid"},
    {{  76.0, -79.0,  -84.0}, 13, "sigmoid"},
    {{  76.0, -79.0,  -55.0}, 13, "sigmoid"},
    {{  78.8, -77.0,  -41.0}, 13, "sigmoid"},
    {{  86.5, -71.0,  -30.8}, 13, "sigmoid"},
    {{  97.0, -63.5,  -27.0}, 13, "sigmoid"},
    {{ 107.5, -54.3,  -30.8}, 13, "sigmoid"},
    {{ 115.2, -47.5,  -41.0}, 13, "sigmoid"},
    {{ 118.0, -45.0,  -55.0}, 13, "sigmoid"},
    {{ 118.0, -45.0,  -81.0}, 14, "sigmoid"},
    {{ 117.0, -45.0, -107.0}, 14, "sigmoid"},
    {{ 116.0, -39.6, -127.0}, 14, "sigmoid"},
    {{ 115.0, -25.0, -141.6}, 14, "sigmoid"},
    {{ 115.0,  -5.0, -147.0}, 15, "sigmoid"},
    {{ 115.0,  15.0, -141.6}, 15, "sigmoid"},
    {{ 116.0,  29.6, -127.0}, 15, "sigmoid"},
    // Descending colon, up the left flank.
    {{ 116.0,  35.0, -107.0}, 15, "descending"},
    {{ 116.0,  38.0,  -80.0}, 16, "descending"},
    {{ 115.0,  38.0,  -40.0}, 17, "descending"},
    {{ 114.0,  34.0,    0.0}, 17, "descending"},
    {{ 112.0,  26.0,   35.0}, 17, "descending"},
    // Splenic flexure, transverse colon sagging across the front, hepatic flexure.
    {{ 108.0,  12.0,   62.0}, 18, "transverse"},
    {{  96.0, -18.0,   84.0}, 20, "transverse"},
    {{  70.0, -55.0,   80.0}, 22, "transverse"},
    {{  42.0, -74.0,   53.0}, 23, "transverse"},
    {{  36.0, -76.0,   38.0}, 23, "transverse"},
    {{  26.0, -78.0,   25.0}, 23, "transverse"},
    {{  13.0, -79.0,   15.0}, 24, "transverse"},
    {{  -2.0, -80.0,    9.0}, 24, "transverse"},
    {{ -18.0, -80.0,    7.0}, 24, "transverse"},
    {{ -34.0, -80.0,    9.0}, 24, "transverse"},
    {{ -49.0, -79.0,   15.0}, 24, "transverse"},
    {{ -62.0, -76.0,   25.0}, 23, "transverse"},
    {{ -72.0, -70.0,   38.0}, 23, "transverse"},
    {{ -80.0, -60.0,   56.0}, 22, "transverse"},
    {{ -90.0, -42.0,   76.0}, 22, "transverse"},
    {{-103.0, -14.0,   84.0}, 22, "transverse"},
    // Ascending colon down the right flank, cecum at the bottom right.
    {{-112.0,  12.0,   72.0}, 23, "ascending"},
    {{-115.0,  26.0,   48.0}, 24, "ascending"},
    {{-115.0,  28.0,   10.0}, 24, "ascending"},
    {{-113.0,  24.0,  -30.0}, 25, "ascending"},
    {{-110.0,  18.0,  -48.0}, 26, "cecum"},
    {{-106.0,  12.0,  -65.0}, 27, "cecum"},
    {{ -98.0,   0.0,  -92.0}, 27, nullptr},
};
// clang-format on

/// A colon path: its control points, rectum -> cecum.
struct ControlTable {
    const ControlPoint* points;
    int count;
};

const ControlTable DEFAULT_COLON{COLON_CONTROL_POINTS,
                                 int(sizeof(COLON_CONTROL_POINTS) / sizeof(ControlPoint))};

// clang-format off
/// The `redundant` colon: the same rectum, descending and ascending colon, with an extra
/// sigmoid loop into the right lower pelvis and a long transverse colon.
const ControlPoint REDUNDANT_CONTROL_POINTS[] = {
#include "phantom_redundant_colon.inc"
};
// clang-format on

const ControlTable REDUNDANT_COLON{REDUNDANT_CONTROL_POINTS,
                                   int(sizeof(REDUNDANT_CONTROL_POINTS) / sizeof(ControlPoint))};

/// Folds, their spacing and depth are part of the fixed anatomy: same for every seed.
constexpr uint64_t ANATOMY_SEED = 0x0C010A11A70D1ull;


/// Samples the spline through the control points at a uniform arc-length step, with a
/// radius that eases between the control radii (no overshoot) and a gentle haustral-scale
/// modulation, clamped to the anatomical range.
void buildCenterline(PhantomAnatomy& a, const ControlTable& table, bool wideRectum)
{
    constexpr int DENSE_PER_SPAN = 512;
    std::vector<Vec3d> dense;
    std::vector<double> denseRadius, denseArc;
    std::vector<int> denseSpan;
    std::vector<Vec3d> controls;
    for (int c = 0; c < table.count; ++c)
        controls.push_back(table.points[c].positionMm);
    const ChordCubicSpline spline(controls);
    for (int span = 0; span + 1 < table.count; ++span) {
        const int first = span == 0 ? 0 : 1;
        for (int k = first; k <= DENSE_PER_SPAN; ++k) {
            const double u = double(k) / DENSE_PER_SPAN;
            const Vec3d p = spline.at(std::size_t(span), u);
            const double r0 = table.points[span].radiusMm;
            const double r1 = table.points[span + 1].radiusMm;
            denseArc.push_back(dense.empty() ? 0.0 : denseArc.back() + distance(dense.back(), p));
            dense.push_back(p);
            denseRadius.push_back(r0 + (r1 - r0) * smoothstep(u));
            denseSpan.push_back(std::min(span, table.count - 2));
        }
    }
    const double totalMm = denseArc.back();
    const auto count = std::size_t(std::floor(totalMm / a.stepMm)) + 1;
    a.centerlineMm.resize(count);
    a.radiusMm.resize(count);
    a.segment.resize(count);
    forEachArcSample(denseArc, a.stepMm, count, [&](std::size_t i, std::size_t d, double w, double s) {
        a.centerlineMm[i] = dense[d] * (1.0 - w) + dense[d + 1] * w;
        const double r = denseRadius[d] * (1.0 - w) + denseRadius[d + 1] * w;
        a.radiusMm[i] = std::clamp(r * (1.0 + 0.04 * std::sin(2.0 * PI * s / 90.0 + 0.6)), 12.0, 28.0);
        if (wideRectum) {
            // Widening from the anal end (kept clear of the image's border) to 30 mm by 20 mm,
            // held to 60 mm, back to the colon's own radius by 100 mm.
            constexpr double WIDE_MM = 30.0;
            const double up = smoothstep(std::clamp(s / 20.0, 0.0, 1.0));
            const double down = 1.0 - smoothstep(std::clamp((s - 60.0) / 40.0, 0.0, 1.0));
            a.radiusMm[i] = std::max(a.radiusMm[i], a.radiusMm[i] + (WIDE_MM - a.radiusMm[i]) * up * down);
        }
        a.segment[i] = table.points[denseSpan[w < 0.5 ? d : d + 1]].segment;
    });
}

} // namespace

namespace detail {

/// Tangents by central differences; normal/binormal by the double-reflection
/// rotation-minimising frame (Wang et al. 2008), so fold angles do not twist.
void buildFrames(PhantomAnatomy& a)
{
    const std::size_t n = a.centerlineMm.size();
    a.tangent.resize(n);
    a.normal.resize(n);
    a.binormal.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t lo = i == 0 ? 0 : i - 1, hi = i + 1 == n ? i : i + 1;
        a.tangent[i] = normalize(a.centerlineMm[hi] - a.centerlineMm[lo]);
    }
    // Start with the normal pointing anteriorly (-y), made orthogonal to the tangent.
    const Vec3d t0 = a.tangent[0];
    Vec3d r0 = Vec3d{0, -1, 0} - t0 * dot(Vec3d{0, -1, 0}, t0);
    if (length(r0) < 1e-6)
        r0 = Vec3d{1, 0, 0} - t0 * t0.x;
    a.normal[0] = normalize(r0);
    for (std::size_t i = 0; i + 1 < n; ++i) {
        const Vec3d v1 = a.centerlineMm[i + 1] - a.centerlineMm[i];
        const double c1 = dot(v1, v1);
        const Vec3d rL = a.normal[i] - v1 * (2.0 / c1 * dot(v1, a.normal[i]));
        const Vec3d tL = a.tangent[i] - v1 * (2.0 / c1 * dot(v1, a.tangent[i]));
        const Vec3d v2 = a.tangent[i + 1] - tL;
        const double c2 = dot(v2, v2);
        Vec3d r = c2 > 1e-20 ? rL - v2 * (2.0 / c2 * dot(v2, rL)) : rL;
        r = r - a.tangent[i + 1] * dot(r, a.tangent[i + 1]);
        a.normal[i + 1] = normalize(r);
    }
    for (std::size_t i = 0; i < n; ++i)
        a.binormal[i] = cross(a.tangent[i], a.normal[i]);
}

} // namespace detail

namespace detail {

std::size_t firstIndexOf(const PhantomAnatomy& a, const std::string& name)
{
    const auto it = std::find(a.segment.begin(), a.segment.end(), name);
    if (it == a.segment.end())
        throw std::logic_error("phantom anatomy: no colon segment named " + name);
    return std::size_t(it - a.segment.begin());
}

} // namespace detail

namespace {

/// Semilunar folds every 25-40 mm from the sigmoid to the cecum (none in the rectum),
/// each spanning two thirds of the circumference, successive ones rotated by 120 degrees
/// (the three haustral rows between the teniae coli).
void buildFolds(PhantomAnatomy& a)
{
    std::mt19937_64 rng(ANATOMY_SEED);
    // Whole-millimetre positions, so every fold sits on a centerline sample.
    const auto first = int(firstIndexOf(a, "sigmoid")) + 20;
    const auto last = int(std::floor((a.lengthMm() - a.radiusMm.back() - 15.0) / a.stepMm));
    const double angle0 = uniform(rng, 0.0, 2.0 * PI);
    int k = 0;
    for (int i = first; i <= last; i += int(std::lround(uniform(rng, 25.0, 40.0) / a.stepMm)), ++k) {
        HaustralFold f;
        f.index = i;
        f.arcMm = f.index * a.stepMm;
        f.thicknessMm = uniform(rng, 3.0, 5.0);
        f.tubeRadiusMm = a.radiusMm[std::size_t(f.index)];
        f.depthMm = uniform(rng, 0.25, 0.40) * f.tubeRadiusMm;
        f.centerAngleRad = std::remainder(angle0 + k * (2.0 * PI / 3.0) + uniform(rng, -0.2, 0.2), 2.0 * PI);
        f.halfSectorRad = uniform(rng, 0.95, 1.05) * (2.0 * PI / 3.0);
        a.folds.push_back(f);
    }
}

constexpr double FOLD_CONTACT_CLEARANCE_MM = 20.0;

/// True when arc s lies within `marginMm` of either loop of a contact.
bool nearContact(const PhantomAnatomy& a, double s, double marginMm)
{
    for (const PhantomContact& c : a.contacts)
        if (std::abs(s - c.arcAMm) < marginMm || std::abs(s - c.arcBMm) < marginMm)
            return true;
    return false;
}

/// True when the polyp's sphere stays clear (in arc length) of the folds on both sides.
bool isBetweenFolds(const PhantomAnatomy& a, double arcMm, double radiusMm)
{
    constexpr double CLEARANCE_MM = 1.0;
    for (std::size_t k = 0; k + 1 < a.folds.size(); ++k) {
        const HaustralFold& f0 = a.folds[k];
        const HaustralFold& f1 = a.folds[k + 1];
        if (f0.arcMm < arcMm && arcMm < f1.arcMm)
            return arcMm - radiusMm - CLEARANCE_MM >= f0.arcMm + 0.5 * f0.thicknessMm &&
                   arcMm + radiusMm + CLEARANCE_MM <= f1.arcMm - 0.5 * f1.thicknessMm;
    }
    return false;
}

/// 6-10 polyps of radius 3-12 mm (one of 3 mm, one of at least 10 mm), centred on the
/// lumen wall, radius <= half the local lumen radius, >= 40 mm apart in arc length and
/// >= 60 mm from the ends; at least three sit between two folds. Given diameters: those,
/// by the same placement rules, none required between folds.
void buildPolyps(PhantomAnatomy& a, std::mt19937_64& rng, const std::optional<std::vector<double>>& diametersMm)
{
    constexpr double END_MARGIN_MM = 60.0, MIN_ARC_GAP_MM = 40.0;
    std::vector<double> radii;
    std::vector<int> order;
    std::vector<bool> designated;
    if (diametersMm) {
        for (double d : *diametersMm) radii.push_back(0.5 * d);
        for (std::size_t k = 0; k < radii.size(); ++k) order.push_back(int(k));
        designated.assign(radii.size(), false);
    } else {
        const int count = 6 + int(rng() % 5);
        const auto n = std::size_t(count);
        radii.resize(n);
        for (int k = 0; k < count; ++k)  // stratified over [3, 12] mm
            radii[std::size_t(k)] = 3.0 + 9.0 * (k + uniform01(rng)) / count;
        radii.front() = 3.0;
        radii.back() = std::max(radii.back(), 10.0);
        for (double& r : radii)
            r = std::round(r * 10.0) / 10.0;

        // Between-fold polyps are chosen among those of radius <= 9 mm, which fit in any gap.
        order.resize(n);
        for (int k = 0; k < count; ++k)
            order[std::size_t(k)] = k;
        std::shuffle(order.begin(), order.end(), rng);
        designated.assign(n, false);
        const int wanted = 3 + int(rng() % 2);
        int chosen = 0;
        for (int k : order)
            if (chosen < wanted && radii[std::size_t(k)] <= 9.0) {
                designated[std::size_t(k)] = true;
                ++chosen;
            }
        if (chosen < 3)
            throw std::logic_error("phantom anatomy: too few small polyps to place between folds");
    }

    // Largest first: they have the fewest admissible places.
    std::sort(order.begin(), order.end(),
              [&](int i, int j) { return radii[std::size_t(i)] > radii[std::size_t(j)]; });
    const double lengthMm = a.lengthMm();
    for (int k : order) {
        const double radius = radii[std::size_t(k)];
        bool placed = false;
        for (int attempt = 0; attempt < 20000 && !placed; ++attempt) {
            double s;
            if (designated[std::size_t(k)]) {
                const std::size_t g = std::size_t(rng() % (a.folds.size() - 1));
                const double mid = 0.5 * (a.folds[g].arcMm + a.folds[g + 1].arcMm);
                s = mid + uniform(rng, -3.0, 3.0);
            } else {
                s = uniform(rng, END_MARGIN_MM, lengthMm - END_MARGIN_MM);
            }
            const auto i = std::size_t(std::lround(s / a.stepMm));
            s = double(i) * a.stepMm;
            if (s < END_MARGIN_MM || s > lengthMm - END_MARGIN_MM)
                continue;
            if (radius > 0.5 * a.radiusMm[i])
                continue;
            if (nearContact(a, s, radius + POLYP_CONTACT_CLEARANCE_MM))
                continue;
            if (designated[std::size_t(k)] && !isBetweenFolds(a, s, radius))
                continue;
            bool farEnough = true;
            for (const PhantomPolyp& q : a.polyps)
                farEnough = farEnough && std::abs(q.arcMm - s) >= MIN_ARC_GAP_MM;
            if (!farEnough)
                continue;
            const double phi = uniform(rng, 0.0, 2.0 * PI);
            PhantomPolyp p;
            p.radiusMm = radius;
            p.arcMm = s;
            p.outwardDir = normalize(a.normal[i] * std::cos(phi) + a.binormal[i] * std::sin(phi));
            p.centerMm = a.centerlineMm[i] + p.outwardDir * a.radiusMm[i];
            a.polyps.push_back(p);
            placed = true;
        }
        if (!placed) {
            std::ostringstream msg;
            msg << "phantom anatomy: could not place a polyp of radius " << radius << " mm";
            throw std::logic_error(msg.str());
        }
    }
    for (PhantomPolyp& p : a.polyps)
        p.betweenFolds = isBetweenFolds(a, p.arcMm, p.radiusMm);
    std::sort(a.polyps.begin(), a.polyps.end(),
              [](const PhantomPolyp& p, const PhantomPolyp& q) { return p.arcMm < q.arcMm; });
}

/// Least distance (mm) from a point to the outer wall surface of the colon (negative inside).
double distanceToColonWallMm(const PhantomAnatomy& a, const Vec3d& p)
{
    double best = 1e300;
    for (std::size_t i = 0; i < a.centerlineMm.size(); ++i)
        best = std::min(best, distance(p, a.centerlineMm[i]) - a.radiusMm[i] - COLON_WALL_MM);
    return best;
}

/// 4-8 small-bowel gas pockets of 1-8 mL in the central abdomen, at least 15 mm from the
/// colon wall and from each other, and clear of the spine.
void buildGasPockets(PhantomAnatomy& a, std::mt19937_64& rng)
{
    constexpr double GAP_MM = 15.0;
    const int count = 4 + int(rng() % 5);
    for (int k = 0; k < count; ++k) {
        const double volumeMl = uniform(rng, 1.5, 6.0);
        const double e1 = uniform(rng, 0.75, 1.33), e2 = uniform(rng, 0.75, 1.33);
        const double e3 = 1.0 / (e1 * e2);
        const double base = std::cbrt(3.0 * volumeMl * 1000.0 / (4.0 * PI));
        Ellipsoid e;
        e.semiAxesMm = Vec3d{e1, e2, e3} * base;
        // A uniformly random rotation from a random unit quaternion.
        double q[4];
        double qn = 0;
        for (double& c : q) {
            c = standardNormal(rng);
            qn += c * c;
        }
        qn = std::sqrt(qn);
        for (double& c : q)
            c /= qn;
        const double w = q[0], x = q[1], y = q[2], z = q[3];
        e.axes = {{{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                   {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                   {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}}};
        const double reach = std::max({e.semiAxesMm.x, e.semiAxesMm.y, e.semiAxesMm.z});
        bool placed = false;
        for (int attempt = 0; attempt < 20000 && !placed; ++attempt) {
            e.centerMm = {uniform(rng, -70, 70), uniform(rng, -60, 25), uniform(rng, -90, 50)};
            if (std::hypot(e.centerMm.x, e.centerMm.y - SPINE_CENTER_Y_MM) - SPINE_RADIUS_MM - reach < GAP_MM)
                continue;
            bool clear = distanceToColonWallMm(a, e.centerMm) - reach >= GAP_MM;
            for (const Ellipsoid& o : a.gasPockets) {
                const double oReach = std::max({o.semiAxesMm.x, o.semiAxesMm.y, o.semiAxesMm.z});
                clear = clear && distance(o.centerMm, e.centerMm) - reach - oReach >= GAP_MM;
            }
            placed = clear;
        }
        if (!placed)
            throw std::logic_error("phantom anatomy: could not place a small-bowel gas pocket");
        a.gasPockets.push_back(e);
    }
}

/// The skin outline as a fine polygon (checks only).
std::vector<std::array<double, 2>> skinOutline()
{
    constexpr int SAMPLES = 3600;  // about 0.3 mm apart
    std::vector<std::array<double, 2>> outline(SAMPLES);
    for (int k = 0; k < SAMPLES; ++k) {
        const double t = 2.0 * PI * k / SAMPLES;
        const double s = std::sin(t);
        outline[std::size_t(k)] = {BODY_HALF_WIDTH_MM * std::cos(t),
                                   s * (s < 0 ? BODY_ANTERIOR_DEPTH_MM : BODY_POSTERIOR_DEPTH_MM)};
    }
    return outline;
}

double distanceToOutlineMm(const std::vector<std::array<double, 2>>& outline, double x, double y)
{
    double best = 1e300;
    for (const auto& q : outline)
        best = std::min(best, (x - q[0]) * (x - q[0]) + (y - q[1]) * (y - q[1]));
    return std::sqrt(best);
}

/// Least gap (mm) between non-adjacent walls outside the contacts of a variant with
/// contacts (the bends that make them bring other parts a little nearer too).
constexpr double MIN_WALL_GAP_WITH_CONTACTS_MM = 10.0;

} // namespace

namespace detail {

/// The invariants later tests rely on, as text (empty: all hold).
std::string anatomyProblems(const PhantomAnatomy& a)
{
    std::ostringstream msg;
    if (a.contacts.empty()) {
        const ColonClearance c = colonSelfClearance(a);
        if (c.gapMm < MIN_WALL_GAP_MM)
            msg << "non-adjacent colon walls " << c.gapMm << " mm apart at arc " << c.i << " and "
                << c.j << " mm; ";
    } else {
        const ColonClearance c = colonClearanceOutsideContacts(a);
        if (c.gapMm < MIN_WALL_GAP_WITH_CONTACTS_MM)
            msg << "non-adjacent colon walls " << c.gapMm << " mm apart at arc " << c.i << " and "
                << c.j << " mm, away from the contacts; ";
    }
    const std::size_t n = a.centerlineMm.size();
    for (std::size_t i = 1; i + 1 < n; ++i) {
        // The tube must not fold over on the inside of a bend.
        const double turn = length(a.tangent[i + 1] - a.tangent[i - 1]) / (2.0 * a.stepMm);
        if (turn * (a.radiusMm[i] + COLON_WALL_MM) > (a.variantPath ? 0.95 : 0.8)) {
            msg << "bend too tight at arc " << i << " mm (curvature radius " << 1.0 / turn
                << " mm); ";
            break;
        }
    }
    const auto skin = skinOutline();
    for (std::size_t i = 0; i < n; i += 5) {
        const Vec3d& p = a.centerlineMm[i];
        const double r = a.radiusMm[i] + COLON_WALL_MM;
        const bool inside = bodySignedDistanceMm(p.x, p.y) < 0;
        if (!inside || distanceToOutlineMm(skin, p.x, p.y) - r < 15.0) {
            msg << "colon within 15 mm of the skin at arc " << i << " mm; ";
            break;
        }
        if (std::abs(p.z) + r > 187.5 - 10.0) {
            msg << "colon within 10 mm of the image's z border at arc " << i << " mm; ";
            break;
        }
        if (std::hypot(p.x, p.y - SPINE_CENTER_Y_MM) - SPINE_RADIUS_MM - r < 10.0) {
            msg << "colon within 10 mm of the spine at arc " << i << " mm; ";
            break;
        }
        for (const Ellipsoid& lung : a.lungs)
            if (lung.signedDistanceMm(p) - r < 15.0) {
                msg << "colon within 15 mm of a lung at arc " << i << " mm; ";
                i = n;
                break;
            }
    }
    return msg.str();
}

} // namespace detail

namespace {

/// The invariants later tests rely on; a failure is a bug in the tables above.
void checkAnatomy(const PhantomAnatomy& a)
{
    const std::string problems = anatomyProblems(a);
    if (!problems.empty())
        throw std::logic_error("phantom anatomy: " + problems);
}

} // namespace

namespace detail {

/// Nearest centerline sample of an arc length, clamped to the curve.
std::size_t sampleAt(const PhantomAnatomy& a, double arcMm)
{
    const long last = long(a.centerlineMm.size()) - 1;
    return std::size_t(std::clamp(std::lround(arcMm / a.stepMm), 0L, last));
}

} // namespace detail

double Ellipsoid::volumeMl() const
{
    return 4.0 / 3.0 * PI * semiAxesMm.x * semiAxesMm.y * semiAxesMm.z / 1000.0;
}

double Ellipsoid::signedDistanceMm(const Vec3d& p) const
{
    const Vec3d d = p - centerMm;
    // Local coordinates: project on the axis columns.
    const Vec3d q{axes[0][0] * d.x + axes[1][0] * d.y + axes[2][0] * d.z,
                  axes[0][1] * d.x + axes[1][1] * d.y + axes[2][1] * d.z,
                  axes[0][2] * d.x + axes[1][2] * d.y + axes[2][2] * d.z};
    const Vec3d u{q.x / semiAxesMm.x, q.y / semiAxesMm.y, q.z / semiAxesMm.z};
    const double f = length(u);
    if (f < 1e-12)
        return -std::min({semiAxesMm.x, semiAxesMm.y, semiAxesMm.z});
    const Vec3d g{u.x / semiAxesMm.x, u.y / semiAxesMm.y, u.z / semiAxesMm.z};
    return (f - 1.0) * f / length(g);
}

double HaustralFold::signedDistanceMm(const Vec3d& p, const Vec3d& centerMm, const Vec3d& tangent,
                                      const Vec3d& normal, const Vec3d& binormal) const
{
    const Vec3d v = p - centerMm;
    const double u = dot(v, tangent);
    const Vec3d w = v - tangent * u;
    const double rho = length(w);
    const double delta = std::abs(std::remainder(std::atan2(dot(w, binormal), dot(w, normal)) - centerAngleRad, 2.0 * PI));
    if (delta >= halfSectorRad)
        return 1e9;
    // Semilunar: the protrusion falls off as a half-ellipse towards the sector's ends.
    const double q = delta / halfSectorRad;
    const double depth = depthMm * std::sqrt(1.0 - q * q);
    const double rimRadius = tubeRadiusMm - depth + 0.5 * thicknessMm;  // centre of the rounded edge
    return std::hypot(u, std::max(0.0, rimRadius - rho)) - 0.5 * thicknessMm;
}

double bodySignedDistanceMm(double x, double y)
{
    const double a = BODY_HALF_WIDTH_MM;
    const double b = y < 0 ? BODY_ANTERIOR_DEPTH_MM : BODY_POSTERIOR_DEPTH_MM;
    const double ux = x / a, uy = y / b;
    const double f = std::hypot(ux, uy);
    if (f < 1e-12)
        return -std::min(a, b);
    return (f - 1.0) * f / std::hypot(ux / a, uy / b);
}

double bodyInnerSignedDistanceMm(double x, double y)
{
    const double a = BODY_HALF_WIDTH_MM - SUBCUTANEOUS_FAT_MM;
    const double b = (y < 0 ? BODY_ANTERIOR_DEPTH_MM : BODY_POSTERIOR_DEPTH_MM) - SUBCUTANEOUS_FAT_MM;
    const double ux = x / a, uy = y / b;
    const double f = std::hypot(ux, uy);
    if (f < 1e-12)
        return -std::min(a, b);
    return (f - 1.0) * f / std::hypot(ux / a, uy / b);
}

namespace {
/// The closest pair of non-adjacent centerline points (wall-to-wall gap), over the pairs `counts`
/// accepts (counts(i, j, gap)).
template <typename Counts> ColonClearance closestWalls(const PhantomAnatomy& a, Counts&& counts)
{
    ColonClearance best;
    const std::size_t n = a.centerlineMm.size();
    const auto skip = std::size_t(std::ceil(NON_ADJACENT_ARC_MM / a.stepMm)) + 1;
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t j = i + skip; j < n; ++j) {
            const double gap = distance(a.centerlineMm[i], a.centerlineMm[j]) - a.radiusMm[i] -
                               a.radiusMm[j] - 2.0 * COLON_WALL_MM;
            if (gap < best.gapMm && counts(i, j, gap))
                best = {gap, i, j};
        }
    return best;
}
} // namespace

ColonClearance colonSelfClearance(const PhantomAnatomy& a)
{
    return closestWalls(a, [](std::size_t, std::size_t, double) { return true; });
}

ColonClearance colonClearanceOutsideContacts(const PhantomAnatomy& a)
{
    return closestWalls(a, [&](std::size_t i, std::size_t j, double gap) {
        bool inWindow = false;
        for (std::size_t c = 0; c < a.contacts.size() && !inWindow; ++c) {
            const double w = a.contactWindowMm[c] + 10.0;
            inWindow = std::abs(double(i) * a.stepMm - a.contacts[c].arcAMm) <= w &&
                       std::abs(double(j) * a.stepMm - a.contacts[c].arcBMm) <= w;
        }
        // Inside a window the walls may meet, but the lumens stay two walls apart.
        return !(inWindow && gap > -0.75);
    });
}

double contactSignedDistanceMm(const PhantomContact& c, const Vec3d& p)
{
    const Vec3d d = p - c.positionMm;
    const double along = dot(d, c.axis);
    const Vec3d acrossV = d - c.axis * along;
    // Box: along in [-halfLengthA, halfLengthB], the two across coordinates in +-width/2.
    // The axis is a world axis, so the across components are the other two coordinates.
    const double e[3] = {0.5 * (c.halfLengthAMm + c.halfLengthBMm), 0.5 * c.widthMm, 0.5 * c.widthMm};
    const double mid = 0.5 * (c.halfLengthBMm - c.halfLengthAMm);
    int k = 0;
    for (int a = 1; a < 3; ++a)
        if (std::abs(c.axis[a]) > std::abs(c.axis[k]))
            k = a;
    const double q[3] = {std::abs(along - mid) - e[0], std::abs(acrossV[(k + 1) % 3]) - e[1],
                         std::abs(acrossV[(k + 2) % 3]) - e[2]};
    const double outside = std::sqrt(std::max(q[0], 0.0) * std::max(q[0], 0.0) +
                                     std::max(q[1], 0.0) * std::max(q[1], 0.0) +
                                     std::max(q[2], 0.0) * std::max(q[2], 0.0));
    return outside + std::min(std::max({q[0], q[1], q[2]}), 0.0);
}

TubeDistance rectalTubeDistance(const PhantomRectalTube& tube, const Vec3d& p)
{
    TubeDistance out;
    const std::vector<Vec3d>& c = tube.axisMm;
    double best2 = 1e300;
    for (std::size_t i = 0; i + 1 < c.size(); ++i) {
        const Vec3d d = c[i + 1] - c[i];
        const double t = std::clamp(dot(p - c[i], d) / dot(d, d), 0.0, 1.0);
        const Vec3d q = p - (c[i] + d * t);
        best2 = std::min(best2, dot(q, q));
    }
    out.axisMm = std::sqrt(best2);
    if (c.size() >= 2)
        out.beyondTipMm = dot(p - c.back(), normalize(c.back() - c[c.size() - 2]));
    return out;
}

PhantomRectalTube makeRectalTube(const PhantomAnatomy& a)
{
    // From the outer end, out in the air behind the buttocks (posterior, to the right of
    // the spine), forwards and up through the pelvic floor to the anal verge (the first
    // centerline point), then up the rectum's axis to the tip, 40 mm above the verge.
    PhantomRectalTube tube;
    const Vec3d verge = a.centerlineMm.front();
    const Vec3d tip = a.centerlineMm[std::size_t(std::lround(40.0 / a.stepMm))];
    tube.axisMm = {{-50.0, 150.0, -180.0}, {-45.0, 85.0, -180.0}, {-22.0, 35.0, -171.0}, verge, tip};
    tube.innerRadiusMm = 3.5;
    tube.outerRadiusMm = 5.5;
    tube.wallHu = 200.0;
    return tube;
}

ImageGeometry phantomGeometry(PhantomSize size)
{
    ImageGeometry g;
    switch (size) {
    case PhantomSize::Small:
        g.size = {160, 160, 150};
        g.spacingMm = {2.5, 2.5, 2.5};
        break;
    case PhantomSize::Medium:
        g.size = {256, 256, 250};
        g.spacingMm = {1.5625, 1.5625, 1.5};
        break;
    case PhantomSize::Full:
        g.size = {512, 512, 450};
        g.spacingMm = {0.78125, 0.78125, 375.0 / 450.0};
        break;
    }
    // Centred on the world origin: the field of view spans [-200, 200] x [-200, 200] x
    // [-187.5, 187.5] mm at every size.
    for (int c = 0; c < 3; ++c)
        g.originMm[c] = -0.5 * double(g.size[std::size_t(c)] - 1) * g.spacingMm[c];
    g.direction = identityMat3();
    return g;
}

PhantomAnatomy buildPhantomAnatomy(uint64_t seed) { return buildPhantomAnatomy(seed, AnatomyOptions{}); }

PhantomAnatomy buildPhantomAnatomy(uint64_t seed, const AnatomyOptions& options)
{
    if (options.touching < 0 || options.touching > PHANTOM_MAX_CONTACTS)
        throw ParameterError("phantom touching: expected 0.." + std::to_string(PHANTOM_MAX_CONTACTS) +
                             ", got " + std::to_string(options.touching));
    PhantomAnatomy a;
    // Lungs: bases of the lower lobes, posterior-lateral, above the colon's flexures.
    a.lungs[0].centerMm = {-85, 15, 152};
    a.lungs[1].centerMm = {85, 15, 152};
    a.lungs[0].semiAxesMm = a.lungs[1].semiAxesMm = {55, 60, 27};
    a.variantPath = options.redundant || options.touching > 0 || options.wideRectum;
    buildCenterline(a, options.redundant ? REDUNDANT_COLON : DEFAULT_COLON, options.wideRectum);
    buildFrames(a);
    if (options.touching > 0)
        addContacts(a, options.touching, seed, options.voxelMm);
    buildFolds(a);
    if (!a.contacts.empty()) {
        // No fold where a contact's channel opens into a lumen.
        std::vector<HaustralFold> kept;
        for (const HaustralFold& f : a.folds)
            if (!nearContact(a, f.arcMm, FOLD_CONTACT_CLEARANCE_MM + 0.5 * f.thicknessMm))
                kept.push_back(f);
        a.folds = kept;
    }
    if (options.rectalTube) {
        a.hasRectalTube = true;
        a.rectalTube = makeRectalTube(a);
    }
    checkAnatomy(a);

    std::mt19937_64 rng(splitmix64(seed ^ 0x9E1F0C5EEDull));
    buildPolyps(a, rng, options.polypDiametersMm);
    buildGasPockets(a, rng);
    return a;
}

} // namespace flyover::phantom
