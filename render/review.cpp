#include "render/review.h"
#include "volume/vec3.h"

#include "volume/error.h"
#include "volume/object_pool.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <queue>
#include <sstream>
#include <unordered_map>

namespace flyover {

namespace {

void validate(const ReviewParams& p)
{
    std::ostringstream msg;
    if (!(p.targetFraction > 0.0 && p.targetFraction <= 1.0))
        msg << "ReviewParams.targetFraction must be in (0, 1], got " << p.targetFraction;
    else if (!(p.minRegionMm2 >= 0.0) || !std::isfinite(p.minRegionMm2))
        msg << "ReviewParams.minRegionMm2 must be >= 0, got " << p.minRegionMm2;
    else if (p.maxViews < 0) msg << "ReviewParams.maxViews must be >= 0, got " << p.maxViews;
    else if (p.maxRounds < 1) msg << "ReviewParams.maxRounds must be >= 1, got " << p.maxRounds;
    else if (!(p.minGainMm2 > 0.0) || !std::isfinite(p.minGainMm2))
        msg << "ReviewParams.minGainMm2 must be > 0, got " << p.minGainMm2;
    else {
        for (const double s : p.shiftsMm)
            if (!std::isfinite(s)) msg << "ReviewParams.shiftsMm must be finite";
        for (const double e : p.elevationFactors)
            if (!(e > 0.0) || !std::isfinite(e)) msg << "ReviewParams.elevationFactors must be > 0, got " << e;
        if (!(p.rollStepDeg >= 0.0 && p.rollStepDeg <= 360.0))
            msg << "ReviewParams.rollStepDeg must be in [0, 360], got " << p.rollStepDeg;
        if (msg.str().empty()) return;
    }
    throw ParameterError(msg.str());
}

/// A candidate view and the triangles it shows that were unseen when its round began.
struct ViewCandidate {
    ReviewView view;
    std::vector<uint32_t> shows;  ///< sorted, unique
};

/// Area-weighted sum of a region's face normals (lumen side; not normalised) and the largest
/// distance of its triangle centroids from `centroid`.
void regionShape(const RayScene& scene, const TriangleGeometry& geo, const std::vector<uint32_t>& tris,
                 const Vec3d& centroid, Vec3d& normalSum, double& extentMm)
{
    normalSum = {0, 0, 0};
    extentMm = 0;
    for (const uint32_t f : tris) {
        const auto v = scene.triangle(f);
        const Vec3d a = scene.vertex(v[0]), b = scene.vertex(v[1]), c = scene.vertex(v[2]);
        normalSum += cross(b - a, c - a) * 0.5;
        extentMm = std::max(extentMm, distance(geo.centroidMm[f], centroid));
    }
}

/// A single camera at `position` looking at `target`, no near plane.
Camera aimedCamera(const Vec3d& position, const Vec3d& target, const Vec3d& upHint, double fovDeg)
{
    Camera c = lookAt(position, target, upHint, fovDeg);
    c.nearMm = 0.0;
    return c;
}

/// True when a front face other than the region's own lies between `from` and `to` (with OST:
/// what a camera at `from` would see first on the way).
bool blocked(const RayScene& scene, const Vec3d& from, const Vec3d& to, const std::vector<uint8_t>& inRegion)
{
    const Vec3d d = to - from;
    const double len = length(d);
    if (!(len > 1e-6)) return false;
    const RayHit h = scene.intersect(from, d / len, 0.0, len, true);
    return h.hit && h.t < len - 0.5 && !inRegion[h.primId];
}

/// True when `eye` is inside the lumen, as far as straight lines tell: the segment from the
/// centerline point `i0`, or one up to 20 points either side, to it crosses no surface.
bool inLumen(const RayScene& scene, const Centerline& cl, std::size_t i0, const Vec3d& eye)
{
    for (const long k : {0L, -5L, 5L, -10L, 10L, -20L, 20L}) {
        const long j = std::clamp(long(i0) + k, 0L, long(cl.points.size()) - 1);
        const Vec3d from = cl.points[std::size_t(j)].positionMm;
        const Vec3d d = eye - from;
        const double len = length(d);
        if (!(len > 1e-6)) return true;
        if (!scene.intersect(from, d / len, 0.0, len, false).hit) return true;
    }
    return false;
}

/// The candidates for one region (see the file comment of review.h).
std::vector<ViewCandidate> candidatesFor(const RayScene& scene, const Centerline& cl, const CoverageParams& cov,
                                     const std::vector<double>& frameRadii, const ReviewParams& params,
                                     const TriangleGeometry& geo, const MissedRegion& region,
                                     const std::vector<uint32_t>& tris, std::vector<uint8_t>& inRegion, int round)
{
    std::vector<ViewCandidate> out;
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    const std::size_t i0 = region.nearestCenterlineIndex;
    auto base = [&](const char* kind) {
        ViewCandidate c;
        c.view.kind = kind;
        c.view.round = round;
        c.view.regionCentroidMm = region.centroidMm;
        c.view.regionAreaMm2 = region.areaMm2;
        return c;
    };
    auto addPair = [&](const char* kind, std::size_t j, double rollDeg, double elevation) {
        ViewCandidate c = base(kind);
        FlyoverParams fp = cov.flyover;
        fp.rollDeg = rollDeg;
        const double frame = frameRadii[j] * elevation;
        const auto cams = flyoverCameras(cl.points[j], fp, frame);
        c.view.cameras.assign(cams.begin(), cams.end());
        c.view.centerlineIndex = j;
        c.view.arcMm = double(j) * step;
        c.view.rollDeg = rollDeg;
        c.view.frameRadiusMm = frame;
        out.push_back(std::move(c));
    };
    for (const double shift : params.shiftsMm) {
        const long j = std::clamp(long(i0) + long(std::llround(shift / step)), 0L, long(cl.points.size()) - 1);
        if (shift != 0.0 && std::size_t(j) == i0) continue;  // clamped onto the region's own point
        const CenterlinePoint& q = cl.points[std::size_t(j)];
        double roll = 0;
        try {
            roll = centredRollDeg(q, region.centroidMm - q.positionMm);
        } catch (const InputError&) {
            continue;  // the region lies on the tangent's line: no roll centres it
        }
        const int turns = shift == 0.0 && params.rollStepDeg > 0.0 ? int(std::ceil(360.0 / params.rollStepDeg - 1e-9)) : 1;
        for (int k = 0; k < turns; ++k) {
            double r = roll + double(k) * params.rollStepDeg;
            r = std::remainder(r, 360.0);
            for (const double e : params.elevationFactors) {
                const char* kind = shift != 0.0 ? "moved_pair" : (e != 1.0 ? "elevation_pair" : "rolled_pair");
                addPair(kind, std::size_t(j), r, e);
            }
        }
    }
    if (!params.targetedViews) return out;

    for (const uint32_t f : tris) inRegion[f] = 1;
    Vec3d normalSum;
    double extent = 0;
    regionShape(scene, geo, tris, region.centroidMm, normalSum, extent);
    const CenterlinePoint& p = cl.points[i0];
    const Vec3d upHint = normalize(p.tangent);
    // Targeted cameras stand inside the lumen (inLumen). Along the mean normal, when the region
    // has one (a ring or a closed pocket has none), from a distance that frames it, pulled in
    // while a front face other than its own is between.
    if (length(normalSum) > 0.3 * region.areaMm2) {
        const Vec3d n = normalize(normalSum);
        const RayHit across = scene.intersect(region.centroidMm + n * 0.05, n, 0.0, 1e6, true);
        double dist = std::max(8.0, 1.5 * extent);
        if (across.hit) dist = std::min(dist, 0.6 * across.t);
        for (int k = 0; k < 4 && dist > 1.0; ++k, dist *= 0.5) {
            const Vec3d eye = region.centroidMm + n * dist;
            if (blocked(scene, eye, region.centroidMm, inRegion) || !inLumen(scene, cl, i0, eye)) continue;
            ViewCandidate c = base("targeted_normal");
            c.view.cameras.push_back(aimedCamera(eye, region.centroidMm, upHint, cov.flyover.fovDeg));
            c.view.centerlineIndex = i0;
            c.view.arcMm = double(i0) * step;
            out.push_back(std::move(c));
            break;
        }
    }
    // From the nearest centerline point (and halfway to the region), looking at it.
    for (const double along : {0.0, 0.5}) {
        const Vec3d eye = p.positionMm + (region.centroidMm - p.positionMm) * along;
        if (!(distance(eye, region.centroidMm) > 1.0) || blocked(scene, eye, region.centroidMm, inRegion) ||
            !inLumen(scene, cl, i0, eye))
            continue;
        ViewCandidate c = base("targeted_centerline");
        c.view.cameras.push_back(aimedCamera(eye, region.centroidMm, upHint, cov.flyover.fovDeg));
        c.view.centerlineIndex = i0;
        c.view.arcMm = double(i0) * step;
        out.push_back(std::move(c));
    }
    for (const uint32_t f : tris) inRegion[f] = 0;
    return out;
}

/// Why a region is still missed after the review stopped.
std::string reasonFor(const RayScene& scene, const Centerline& cl, const MissedRegion& r,
                      const std::vector<uint32_t>& tris, std::vector<uint8_t>& inRegion, double bestShown,
                      const ReviewParams& params, const std::string& stopReason)
{
    std::ostringstream why;
    if (!stopReason.empty()) return stopReason;
    if (bestShown > 0.0) {
        why.precision(3);
        why << "seen only in slivers: the best candidate view shows " << bestShown << " mm^2 of it (less than "
            << params.minGainMm2 << " mm^2 of new area)";
        return why.str();
    }
    // No candidate shows any of it: is it across a wall from the path, or behind a fold?
    for (const uint32_t f : tris) inRegion[f] = 1;
    const Vec3d from = cl.points[r.nearestCenterlineIndex].positionMm;
    const Vec3d d = r.centroidMm - from;
    const double len = length(d);
    int crossings = 0;
    if (len > 1e-6) {
        double t0 = 0.0;
        for (int k = 0; k < 16; ++k) {
            const RayHit h = scene.intersect(from, d / len, t0, len, false);
            if (!h.hit) break;
            if (!inRegion[h.primId]) ++crossings;
            t0 = h.t + 1e-3;
        }
    }
    for (const uint32_t f : tris) inRegion[f] = 0;
    if (crossings > 0)
        return "outside the lumen's reach: no candidate view shows any of it and the line from its nearest "
               "centerline point crosses the wall " +
               std::to_string(crossings) + " time(s) (a closed-off pocket or another loop)";
    return "hidden behind a fold from every candidate view (rolled, moved, raised/lowered and targeted)";
}

/// Area of the triangles of `shows` that `seen` does not have yet.
double gainOf(const std::vector<uint32_t>& shows, const std::vector<uint8_t>& seen, const std::vector<double>& area)
{
    double g = 0;
    for (const uint32_t f : shows)
        if (!seen[f]) g += area[f];
    return g;
}

/// Why the regions are left when the review reached its target.
std::string notNeededText(const ReviewParams& params)
{
    std::ostringstream s;
    s << "not needed: fly-over plus review reached the target of " << params.targetFraction * 100.0
      << "% of the wall";
    return s.str();
}

/// The fly-over's own regions (same order as flyover.flyover.missed), to say which one each
/// review view serves: per triangle, the index of its region, or -1.
std::vector<long> flyoverLabels(const RayScene& scene, const Centerline& cl, const CoverageParams& cov,
                                const CoverageResult& flyover)
{
    std::vector<long> flyoverLabel(scene.triangleCount(), -1);
    MethodCoverage alone;
    alone.seen = flyover.flyover.seen;
    std::vector<std::vector<uint32_t>> tris;
    summariseCoverage(alone, scene, cl, cov.minRegionMm2, &tris);
    for (std::size_t k = 0; k < tris.size(); ++k)
        for (const uint32_t f : tris[k]) flyoverLabel[f] = long(k);
    return flyoverLabel;
}

/// Scratch of the task marking one candidate's rays.
struct Worker {
    ViewMarker marker;
    std::vector<uint32_t> shown;
    uint64_t rays = 0;
};

/// Each candidate's rays, marked as the coverage marks the fly-over's: its `shows` receive the
/// triangles it shows that are not `seen` yet. Reports progress within review round `round`.
void markCandidates(std::vector<ViewCandidate>& cands, ObjectPool<Worker>& workers, const std::vector<uint8_t>& seen,
                    const Centerline& cl, const CoverageParams& cov, const ReviewParams& params, int round,
                    Progress* progress)
{
    std::atomic<std::size_t> done{0};
    tbb::parallel_for(std::size_t(0), cands.size(), [&](std::size_t k) {
        const auto lease = workers.take();
        Worker& w = *lease;
        w.shown.clear();
        const LoopWindow loop = cov.loopAt(cands[k].view.centerlineIndex, cl.stepMm);
        for (const Camera& cam : cands[k].view.cameras) w.rays += w.marker.mark(cam, cov.ost, w.shown, loop);
        std::vector<uint32_t>& s = cands[k].shows;
        for (const uint32_t f : w.shown)
            if (!seen[f]) s.push_back(f);
        std::sort(s.begin(), s.end());
        s.erase(std::unique(s.begin(), s.end()), s.end());
        const std::size_t n = ++done;
        if (n % 64 == 0)
            reportProgress(progress, std::min(0.95, (double(round - 1) + double(n) / double(cands.size())) /
                                                        double(params.maxRounds)),
                           "review candidates");
    });
}

/// Greedy with lazy gains (a view's gain only shrinks as others are picked): picks candidates
/// into `views` while one gains at least params.minGainMm2, the target (`total` area times
/// params.targetFraction) is not reached and the budget is not spent; updates `seen` and
/// `seenArea`. Returns the number picked.
std::size_t pickViews(const std::vector<ViewCandidate>& cands, const TriangleGeometry& geo,
                      const std::vector<long>& flyoverLabel, const ReviewParams& params, double total,
                      std::vector<uint8_t>& seen, double& seenArea, std::vector<ReviewView>& views)
{
    using Entry = std::pair<double, std::size_t>;
    std::priority_queue<Entry> queue;
    for (std::size_t k = 0; k < cands.size(); ++k) {
        const double g = gainOf(cands[k].shows, seen, geo.areaMm2);
        if (g >= params.minGainMm2) queue.push({g, k});
    }
    std::size_t picked = 0;
    while (!queue.empty() && seenArea < params.targetFraction * total && int(views.size()) < params.maxViews) {
        const std::size_t k = queue.top().second;
        queue.pop();
        const double g = gainOf(cands[k].shows, seen, geo.areaMm2);
        if (g < params.minGainMm2) continue;
        if (!queue.empty() && g < queue.top().first) {
            queue.push({g, k});
            continue;
        }
        std::unordered_map<long, double> perRegion;
        for (const uint32_t f : cands[k].shows)
            if (!seen[f]) {
                seen[f] = 1;
                if (flyoverLabel[f] >= 0) perRegion[flyoverLabel[f]] += geo.areaMm2[f];
            }
        seenArea += g;
        ReviewView v = cands[k].view;
        v.addedAreaMm2 = g;
        double best = 0;
        for (const auto& [label, a] : perRegion)
            if (a > best || (a == best && label < v.flyoverRegion)) best = a, v.flyoverRegion = label;
        views.push_back(std::move(v));
        ++picked;
    }
    return picked;
}

/// What the last review round left, for the reasons of the regions still missed.
struct LastRound {
    std::vector<ViewCandidate> candidates;
    std::vector<uint8_t> targets;  ///< per triangle: in a region the last round planned for
    std::size_t picked = 0;
};

/// One UnreachedRegion per region of result.withReview.missed (triangles `finalTris`): the
/// most of it a candidate of the last round showed, and why it is still missed.
void explainUnreached(const RayScene& scene, const Centerline& cl, const TriangleGeometry& geo,
                      const ReviewParams& params, const std::vector<std::vector<uint32_t>>& finalTris,
                      const LastRound& last, const std::string& stopReason, std::vector<uint8_t>& inRegion,
                      ReviewResult& result)
{
    for (std::size_t r = 0; r < result.withReview.missed.size(); ++r) {
        UnreachedRegion u;
        u.region = result.withReview.missed[r];
        for (const uint32_t f : finalTris[r]) inRegion[f] = 1;
        for (const ViewCandidate& c : last.candidates) {
            double a = 0;
            for (const uint32_t f : c.shows)
                if (inRegion[f]) a += geo.areaMm2[f];
            u.bestCandidateAreaMm2 = std::max(u.bestCandidateAreaMm2, a);
        }
        for (const uint32_t f : finalTris[r]) inRegion[f] = 0;
        std::string why = stopReason;
        if (why.empty() && result.targetReached) {
            why = notNeededText(params);
        } else if (why.empty() && u.region.areaMm2 < params.minRegionMm2) {
            why = "smaller than the review's minimum region of " + std::to_string(params.minRegionMm2) + " mm^2";
        } else if (why.empty() && last.candidates.empty()) {
            why = "no review round was run";
        } else if (why.empty() && !last.targets[finalTris[r].front()]) {
            why = "not planned: each round plans views for the " + std::to_string(params.maxRegionsPerRound) +
                  " largest regions only";
        } else if (why.empty() && last.picked > 0 && u.bestCandidateAreaMm2 >= params.minGainMm2) {
            why = "the review stopped after its " + std::to_string(params.maxRounds) + " rounds";
        }
        u.reason = reasonFor(scene, cl, u.region, finalTris[r], inRegion, u.bestCandidateAreaMm2, params, why);
        result.unreached.push_back(std::move(u));
    }
}

} // namespace

double centredRollDeg(const CenterlinePoint& point, const Vec3d& directionMm)
{
    // Camera 0 looks along -n(roll) with n(roll) = n0 cos(roll) + b0 sin(roll); it looks straight
    // at the direction's projection d when n(roll) = -d / |d|.
    const FlyoverAxes axes = flyoverAxes(point, 0.0);
    const double a = dot(axes.n, directionMm), c = dot(axes.b, directionMm);
    if (!(std::hypot(a, c) > 1e-9 * std::max(1.0, length(directionMm))))
        throw InputError("centredRollDeg: the direction is parallel to the centerline tangent");
    return std::atan2(-c, -a) * 180.0 / PI;
}

ReviewResult planReview(const RayScene& scene, const Centerline& cl, const CoverageParams& cov,
                        const std::vector<double>& frameRadii, const CoverageResult& flyover,
                        const ReviewParams& params, Progress* progress)
{
    validate(params);
    if (cl.points.empty()) throw InputError("planReview: the centerline is empty");
    const std::size_t nf = scene.triangleCount();
    if (flyover.flyover.seen.size() != nf)
        throw ParameterError("planReview: the fly-over coverage has " + std::to_string(flyover.flyover.seen.size()) +
                             " seen flags for " + std::to_string(nf) + " triangles");
    if (frameRadii.size() != cl.points.size())
        throw ParameterError("planReview: " + std::to_string(frameRadii.size()) + " frame radii for " +
                             std::to_string(cl.points.size()) + " centerline points");

    const TriangleGeometry geo = triangleGeometry(scene, &cl);
    double total = 0;
    for (const double a : geo.areaMm2) total += a;

    ReviewResult result;
    std::vector<uint8_t> seen = flyover.flyover.seen;
    double seenArea = 0;
    for (std::size_t f = 0; f < nf; ++f)
        if (seen[f]) seenArea += geo.areaMm2[f];
    if (seenArea >= params.targetFraction * total) {
        // The fly-over alone meets the target: its own regions are the answer (no mesh walks).
        result.withReview = flyover.flyover;
        result.targetReached = true;
        for (const MissedRegion& r : result.withReview.missed)
            result.unreached.push_back({r, notNeededText(params), 0.0});
        reportProgress(progress, 1.0, "review");
        return result;
    }

    const std::vector<long> flyoverLabel = flyoverLabels(scene, cl, cov, flyover);

    const ViewMarker prototype(scene, cov.viewPx, cov.footprint);
    // One worker per candidate at a time (see ObjectPool: nested ray tiles).
    ObjectPool<Worker> workers([&] { return Worker{prototype, {}, 0}; });
    std::vector<uint8_t> inRegion(nf, 0);
    LastRound last;  // the last round's candidates, targets and picks, for the reasons
    std::string stopReason;
    int roundsRun = 0;
    for (int round = 1; round <= params.maxRounds; ++round) {
        if (seenArea >= params.targetFraction * total) break;
        if (int(result.views.size()) >= params.maxViews) break;
        MethodCoverage current;
        current.seen = seen;
        std::vector<std::vector<uint32_t>> regionTris;
        summariseCoverage(current, scene, cl, params.minRegionMm2, &regionTris);
        if (current.missed.empty()) break;
        roundsRun = round;
        const std::size_t nRegions = std::min(current.missed.size(), params.maxRegionsPerRound);
        std::vector<ViewCandidate> cands;
        for (std::size_t r = 0; r < nRegions; ++r) {
            auto c = candidatesFor(scene, cl, cov, frameRadii, params, geo, current.missed[r], regionTris[r], inRegion,
                                   round);
            for (auto& x : c) cands.push_back(std::move(x));
        }
        markCandidates(cands, workers, seen, cl, cov, params, round, progress);
        result.candidatesEvaluated += cands.size();
        last.targets.assign(nf, 0);
        for (std::size_t r = 0; r < nRegions; ++r)
            for (const uint32_t f : regionTris[r]) last.targets[f] = 1;

        const std::size_t picked = pickViews(cands, geo, flyoverLabel, params, total, seen, seenArea, result.views);
        last.candidates = std::move(cands);
        last.picked = picked;
        if (picked == 0) break;
    }
    if (int(result.views.size()) >= params.maxViews && seenArea < params.targetFraction * total)
        stopReason = "the review's budget of " + std::to_string(params.maxViews) + " views was spent";
    workers.forEach([&](const Worker& w) { result.rays += w.rays; });

    result.withReview.seen = seen;
    std::vector<std::vector<uint32_t>> finalTris;
    summariseCoverage(result.withReview, scene, cl, cov.minRegionMm2, &finalTris);
    result.targetReached = result.withReview.fraction >= params.targetFraction;
    result.rounds = roundsRun;
    explainUnreached(scene, cl, geo, params, finalTris, last, stopReason, inRegion, result);
    reportProgress(progress, 1.0, "review");
    return result;
}

} // namespace flyover
