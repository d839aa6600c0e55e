// The phantom's touching variant: loops far apart along the colon bent against each other
// (phantom_anatomy.h, AnatomyOptions::touching).
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
#include <vector>

namespace flyover::phantom {

using namespace detail;

namespace {

// ---------------------------------------------------------------------------------------
// Contacts: loops far apart along the colon bent against each other.

constexpr double CONTACT_MIN_ARC_MM = 150.0;      ///< least arc between the two loops (truth)
constexpr double CONTACT_PICK_ARC_MM = 175.0;     ///< the same before bending (bends lengthen)
constexpr double CONTACT_MAX_GAP_MM = 90.0;       ///< wall gap a bend may close
constexpr double CONTACT_MAX_BEND_CURVATURE = 1.0 / 120.0;  ///< curvature a bend adds (1/mm)
constexpr double CONTACT_END_MARGIN_MM = 30.0;    ///< from either end of the colon
constexpr int CONTACT_ATTEMPTS = 300;
constexpr double CONTACT_SITE_SPACING_MM = 35.0;
constexpr double CONTACT_LOCAL_MM = 20.0;  ///< neighbourhood in which a site's gap is least  ///< least arc between loops of two contacts

/// Wall-to-wall gap (mm) between two centerline samples: negative when the walls overlap.
double wallGapMm(const std::vector<Vec3d>& c, const std::vector<double>& r, std::size_t i, std::size_t j)
{
    return distance(c[i], c[j]) - r[i] - r[j] - 2.0 * COLON_WALL_MM;
}

/// Arc half-width (mm) of a bend that moves a loop sideways by shiftMm: a cos^2 bump whose
/// added curvature shift * pi^2 / (2 L^2) stays under CONTACT_MAX_BEND_CURVATURE.
double bendHalfWidthMm(double shiftMm, double curvature = CONTACT_MAX_BEND_CURVATURE)
{
    return std::clamp(PI * std::sqrt(std::max(shiftMm, 0.0) / (2.0 * curvature)), 30.0, 170.0);
}

/// Curvatures (1/mm) a bend may add, gentlest first: a site near a tight turn of the colon
/// needs a short bend that stays off the turn.
constexpr double BEND_CURVATURES[] = {1.0 / 120.0, 1.0 / 80.0, 1.0 / 55.0, 1.0 / 40.0};

struct ContactSite {
    std::size_t i = 0, j = 0;   ///< centerline samples (i < j)
    double gapMm = 0;
    double windowMm = 0;        ///< bend half-width
    double curvature = CONTACT_MAX_BEND_CURVATURE;  ///< that the bend may add
};

/// Closest pair (least wall gap) with i, j within `reach` samples of (i0, j0).
ContactSite closestPairNear(const std::vector<Vec3d>& c, const std::vector<double>& r, std::size_t i0,
                            std::size_t j0, std::size_t reach)
{
    ContactSite best{i0, j0, 1e300, 0, CONTACT_MAX_BEND_CURVATURE};
    const std::size_t n = c.size();
    for (std::size_t i = i0 > reach ? i0 - reach : 0; i <= std::min(n - 1, i0 + reach); ++i)
        for (std::size_t j = j0 > reach ? j0 - reach : 0; j <= std::min(n - 1, j0 + reach); ++j) {
            const double g = wallGapMm(c, r, i, j);
            if (g < best.gapMm)
                best = {i, j, g, 0, CONTACT_MAX_BEND_CURVATURE};
        }
    return best;
}

/// Places where two loops far apart along the colon come within CONTACT_MAX_GAP_MM of each
/// other, best (smallest gap) first, their bends' windows apart from each other.
std::vector<ContactSite> contactCandidates(const PhantomAnatomy& a)
{
    const std::vector<Vec3d>& c = a.centerlineMm;
    const std::size_t n = c.size();
    const auto pick = std::size_t(CONTACT_PICK_ARC_MM / a.stepMm);
    const auto margin = std::size_t(CONTACT_END_MARGIN_MM / a.stepMm);
    // Local minima of the gap over pairs (within +-CONTACT_LOCAL_MM of arc on both loops),
    // so that the bend does not slide along a valley of near pairs.
    const auto local = long(CONTACT_LOCAL_MM / a.stepMm);
    std::vector<ContactSite> pairs;
    for (std::size_t i = margin; i + margin < n; i += 2)
        for (std::size_t j = i + pick; j + margin < n; j += 2) {
            const double g = wallGapMm(c, a.radiusMm, i, j);
            if (g >= CONTACT_MAX_GAP_MM)
                continue;
            bool minimum = true;
            for (long di = -local; di <= local && minimum; di += 2)
                for (long dj = -local; dj <= local && minimum; dj += 2) {
                    const long ii = long(i) + di, jj = long(j) + dj;
                    if (ii < 0 || jj < 0 || ii >= long(n) || jj >= long(n) || jj - ii < long(NON_ADJACENT_ARC_MM))
                        continue;
                    minimum = wallGapMm(c, a.radiusMm, std::size_t(ii), std::size_t(jj)) >= g;
                }
            if (minimum)
                pairs.push_back({i, j, g, bendHalfWidthMm(g), CONTACT_MAX_BEND_CURVATURE});
        }
    std::stable_sort(pairs.begin(), pairs.end(),
                     [](const ContactSite& p, const ContactSite& q) { return p.gapMm < q.gapMm; });
    return pairs;
}

/// True when the site's loops are CONTACT_SITE_SPACING_MM clear of every kept site's.
bool apartFrom(const PhantomAnatomy& a, const ContactSite& p, const std::vector<ContactSite>& kept)
{
    for (const ContactSite& q : kept)
        for (std::size_t u : {p.i, p.j})
            for (std::size_t v : {q.i, q.j})
                if (std::abs(double(u) - double(v)) * a.stepMm <= CONTACT_SITE_SPACING_MM)
                    return false;
    return true;
}

/// Resamples a dense polyline (with radii and segment names) at the anatomy's arc step.
/// `oldToNew` receives the new sample index of every old sample.
void resampleCenterline(PhantomAnatomy& a, const std::vector<Vec3d>& p, const std::vector<double>& r,
                        const std::vector<std::string>& seg, std::vector<std::size_t>& oldToNew)
{
    std::vector<double> arc(p.size(), 0.0);
    for (std::size_t k = 1; k < p.size(); ++k)
        arc[k] = arc[k - 1] + distance(p[k - 1], p[k]);
    const auto count = std::size_t(std::floor(arc.back() / a.stepMm)) + 1;
    a.centerlineMm.resize(count);
    a.radiusMm.resize(count);
    a.segment.resize(count);
    forEachArcSample(arc, a.stepMm, count, [&](std::size_t i, std::size_t d, double w, double) {
        a.centerlineMm[i] = p[d] * (1.0 - w) + p[d + 1] * w;
        a.radiusMm[i] = r[d] * (1.0 - w) + r[d + 1] * w;
        a.segment[i] = seg[w < 0.5 ? d : d + 1];
    });
    oldToNew.resize(p.size());
    for (std::size_t k = 0; k < p.size(); ++k)
        oldToNew[k] = std::min(count - 1, std::size_t(std::lround(arc[k] / a.stepMm)));
}

double mobility(const std::string& segment)
{
    return segment == "sigmoid" || segment == "transverse" ? 1.0 : 0.0;
}

/// Moves the loops of each site towards each other with cos^2 bumps until their walls meet
/// (three passes: the closest pair shifts a little as the loops bend).
std::vector<Vec3d> bendTogether(const PhantomAnatomy& a, std::vector<ContactSite>& sites)
{
    std::vector<Vec3d> p = a.centerlineMm;
    const std::size_t n = p.size();
    for (int pass = 0; pass < 5; ++pass)
        for (ContactSite& site : sites) {
            const ContactSite now = closestPairNear(p, a.radiusMm, site.i, site.j, 25);
            // The mobile parts (on a mesentery: sigmoid, transverse) move; the fixed ones
            // (rectum, descending, ascending, cecum) only when both are fixed.
            const double ma = mobility(a.segment[now.i]), mb = mobility(a.segment[now.j]);
            const double fa = ma + mb > 0 ? ma / (ma + mb) : 0.5;
            const double shift[2] = {now.gapMm * fa, -now.gapMm * (1.0 - fa)};
            if (pass == 0)
                site.windowMm = bendHalfWidthMm(std::max(std::abs(shift[0]), std::abs(shift[1])), site.curvature);
            site.i = now.i;
            site.j = now.j;
            const Vec3d dir = normalize(p[now.j] - p[now.i]);
            const double half = site.windowMm;
            for (std::size_t k = 0; k < n; ++k) {
                for (int side = 0; side < 2; ++side) {
                    const double t = (double(k) - double(side == 0 ? now.i : now.j)) * a.stepMm;
                    if (std::abs(t) >= half)
                        continue;
                    const double w = std::cos(0.5 * PI * t / half);
                    p[k] += dir * (shift[side] * w * w);
                }
            }
        }
    return p;
}

/// Fills contact.axis, widthMm and the half-lengths of the channel from the sampled loops.
/// Returns false when the channel would not reach both lumens.
bool shapeContactChannel(const PhantomAnatomy& a, PhantomContact& contact, std::size_t ia, std::size_t ib,
                         const Vec3d& voxelMm, std::mt19937_64& rng)
{
    const Vec3d u = normalize(a.centerlineMm[ib] - a.centerlineMm[ia]);
    const double deep = std::max({voxelMm.x, voxelMm.y, voxelMm.z});
    const double fraction = uniform(rng, 1.3, 1.7);
    // How far along -axis (towards A) or +axis (towards B) the channel goes: a voxel past
    // the first point half a voxel inside that loop's lumen (and still inside it there).
    const auto lumenSd = [&](std::size_t centre, const Vec3d& q) {
        double sd = 1e300;
        for (std::size_t i = centre > 40 ? centre - 40 : 0; i < std::min(a.centerlineMm.size(), centre + 41); ++i)
            sd = std::min(sd, distance(q, a.centerlineMm[i]) - a.radiusMm[i]);
        return sd;
    };
    const auto reach = [&](std::size_t centre, double sign, double& out) {
        for (double t = 0.0; t <= 30.0; t += 0.05) {
            if (lumenSd(centre, contact.positionMm + contact.axis * (sign * t)) < -0.5 * deep) {
                out = t + deep;
                return lumenSd(centre, contact.positionMm + contact.axis * (sign * out)) < -0.5 * deep;
            }
        }
        return false;
    };
    // The world axes, nearest to the line between the loops first; the first whose channel
    // reaches into both lumens.
    int order[3] = {0, 1, 2};
    std::sort(order, order + 3, [&](int p, int q) { return std::abs(u[p]) > std::abs(u[q]); });
    for (int k : order) {
        if (std::abs(u[k]) < 0.3)
            break;
        contact.axis = Vec3d{0, 0, 0};
        contact.axis[k] = u[k] > 0 ? 1.0 : -1.0;
        const double across = std::max(voxelMm[(k + 1) % 3], voxelMm[(k + 2) % 3]);
        contact.widthMm = std::round(fraction * across * 100.0) / 100.0;
        if (reach(ia, -1.0, contact.halfLengthAMm) && reach(ib, 1.0, contact.halfLengthBMm))
            return true;
    }
    return false;
}

/// Bends the base colon at the sites; the anatomy with its contacts, or the problem.
bool tryContacts(const PhantomAnatomy& base, std::vector<ContactSite> sites, const Vec3d& voxelMm,
                 std::mt19937_64& rng, PhantomAnatomy& out, std::string& problem)
{
    std::sort(sites.begin(), sites.end(), [](const ContactSite& p, const ContactSite& q) { return p.i < q.i; });
    PhantomAnatomy trial = base;
    const std::vector<Vec3d> bent = bendTogether(base, sites);
    std::vector<std::size_t> oldToNew;
    resampleCenterline(trial, bent, base.radiusMm, base.segment, oldToNew);
    buildFrames(trial);
    bool ok = true;
    for (const ContactSite& site : sites) {
        const ContactSite now = closestPairNear(trial.centerlineMm, trial.radiusMm, oldToNew[site.i],
                                                oldToNew[site.j], 12);
        const double lumenGap = now.gapMm + 2.0 * COLON_WALL_MM;
        PhantomContact contact;
        contact.arcAMm = double(now.i) * trial.stepMm;
        contact.arcBMm = double(now.j) * trial.stepMm;
        const Vec3d ca = trial.centerlineMm[now.i], cb = trial.centerlineMm[now.j];
        contact.positionMm = ca + normalize(cb - ca) * (trial.radiusMm[now.i] + 0.5 * lumenGap);
        ok = ok && std::abs(now.gapMm) < 0.75 && contact.arcBMm - contact.arcAMm >= CONTACT_MIN_ARC_MM &&
             shapeContactChannel(trial, contact, now.i, now.j, voxelMm, rng);
        trial.contacts.push_back(contact);
        trial.contactWindowMm.push_back(site.windowMm);
    }
    // Distinct places: no two contacts share a loop within the site spacing.
    for (std::size_t x = 0; x < trial.contacts.size(); ++x)
        for (std::size_t y = x + 1; y < trial.contacts.size(); ++y)
            for (double u : {trial.contacts[x].arcAMm, trial.contacts[x].arcBMm})
                for (double v : {trial.contacts[y].arcAMm, trial.contacts[y].arcBMm})
                    ok = ok && std::abs(u - v) >= CONTACT_SITE_SPACING_MM;
    if (!ok) {
        problem = "a bend did not close its gap, or two contacts merged";
        return false;
    }
    problem = anatomyProblems(trial);
    if (!problem.empty())
        return false;
    out = trial;
    return true;
}

} // namespace

namespace detail {

/// The `touching` variant: `count` contacts, chosen among the sites where a bend alone
/// keeps every invariant, by a random stream of their own; the first choice whose bent
/// colon keeps them all.
void addContacts(PhantomAnatomy& a, int count, uint64_t seed, const Vec3d& voxelMm)
{
    std::mt19937_64 rng(splitmix64(seed ^ 0xC0117AC75ull));
    std::vector<ContactSite> viable;
    for (ContactSite site : contactCandidates(a)) {
        // At least one of the two loops must be mobile (sigmoid, transverse), and the site
        // a place of its own.
        if (mobility(a.segment[site.i]) + mobility(a.segment[site.j]) == 0.0 || !apartFrom(a, site, viable))
            continue;
        for (double curvature : BEND_CURVATURES) {
            site.curvature = curvature;
            PhantomAnatomy single;
            std::string problem;
            std::mt19937_64 scratch(0);
            if (tryContacts(a, {site}, voxelMm, scratch, single, problem)) {
                viable.push_back(site);
                break;
            }
        }
    }
    if (int(viable.size()) < count) {
        std::ostringstream msg;
        msg << "phantom touching: this colon has room for at most " << viable.size() << " contacts, "
            << count << " asked (the default colon has room for 2, the redundant one for 5)";
        throw ParameterError(msg.str());
    }
    std::string lastProblem;
    for (int attempt = 0; attempt < CONTACT_ATTEMPTS; ++attempt) {
        std::vector<std::size_t> order(viable.size());
        for (std::size_t k = 0; k < order.size(); ++k)
            order[k] = k;
        std::shuffle(order.begin(), order.end(), rng);
        std::vector<ContactSite> sites;
        for (int k = 0; k < count; ++k)
            sites.push_back(viable[order[std::size_t(k)]]);
        if (tryContacts(a, sites, voxelMm, rng, a, lastProblem))
            return;
    }
    throw std::logic_error("phantom anatomy: could not place " + std::to_string(count) +
                           " contacts (" + lastProblem + ")");
}


} // namespace detail

} // namespace flyover::phantom
