#include "render/coverage.h"

#include "render/flyover_path.h"

#include "render/ray_scene_impl.h"
#include "render/render_view.h"
#include "volume/error.h"
#include "volume/object_pool.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

/// Triangles around each vertex (compressed rows), for the edge neighbours of a triangle; and,
/// for the footprint walk, each triangle's edge neighbours (compressed rows), built once per
/// mesh instead of once per ray.
struct ViewMarker::Topology {
    std::vector<uint32_t> start;  ///< triangles of vertex v: list[start[v] .. start[v + 1])
    std::vector<uint32_t> list;
    /// Triangles sharing an edge with triangle f (every g != f that holds both ends of one of
    /// f's edges, as the walk over `list` finds them; non-manifold edges give more than one):
    /// neighbours[neighbourStart[f] .. neighbourStart[f + 1]).
    std::vector<uint32_t> neighbourStart;
    std::vector<uint32_t> neighbours;

    /// `withRows` false: only the triangles around each vertex (what summarise needs).
    explicit Topology(const RayScene::Impl& im, bool withRows = true)
    {
        const std::size_t nv = im.vertices.size() - 1;
        start.assign(nv + 1, 0);
        for (const uint32_t v : im.indices) ++start[v + 1];
        for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
        list.resize(im.indices.size());
        std::vector<uint32_t> fill(start.begin(), start.end() - 1);
        for (std::size_t k = 0; k < im.indices.size(); ++k) list[fill[im.indices[k]]++] = uint32_t(k / 3);

        if (!withRows) return;
        const std::size_t nf = im.triangles;
        // Edge neighbours of f, sorted and unique, into `found`.
        auto neighboursOf = [&](std::size_t f, std::vector<uint32_t>& found) {
            const uint32_t* t = &im.indices[3 * f];
            found.clear();
            for (int e = 0; e < 3; ++e) {
                const uint32_t a = t[e], b = t[(e + 1) % 3];
                for (uint32_t k = start[a]; k < start[a + 1]; ++k) {
                    const uint32_t g = list[k];
                    if (g == uint32_t(f)) continue;
                    const uint32_t* u = &im.indices[3 * std::size_t(g)];
                    if (u[0] == b || u[1] == b || u[2] == b) found.push_back(g);
                }
            }
            std::sort(found.begin(), found.end());
            found.erase(std::unique(found.begin(), found.end()), found.end());
        };
        // Two parallel passes: count, then fill the rows.
        neighbourStart.assign(nf + 1, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf), [&](const tbb::blocked_range<std::size_t>& r) {
            std::vector<uint32_t> found;
            for (std::size_t f = r.begin(); f != r.end(); ++f) {
                neighboursOf(f, found);
                neighbourStart[f + 1] = uint32_t(found.size());
            }
        });
        for (std::size_t f = 0; f < nf; ++f) neighbourStart[f + 1] += neighbourStart[f];
        neighbours.resize(neighbourStart[nf]);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf), [&](const tbb::blocked_range<std::size_t>& r) {
            std::vector<uint32_t> found;
            for (std::size_t f = r.begin(); f != r.end(); ++f) {
                neighboursOf(f, found);
                std::copy(found.begin(), found.end(), neighbours.begin() + neighbourStart[f]);
            }
        });
    }
};

namespace {

using VertexTriangles = ViewMarker::Topology;

void validate(const CoverageParams& p)
{
    std::ostringstream msg;
    if (!(p.viewPx >= 8 && p.viewPx <= 4096)) msg << "CoverageParams.viewPx must be in 8..4096, got " << p.viewPx;
    else if (!(p.stepMm > 0.0) || !std::isfinite(p.stepMm)) msg << "CoverageParams.stepMm must be > 0, got " << p.stepMm;
    else if (!(p.flythroughFovDeg > 0.0 && p.flythroughFovDeg < 180.0))
        msg << "CoverageParams.flythroughFovDeg must be in (0, 180), got " << p.flythroughFovDeg;
    else if (!(p.minRegionMm2 >= 0.0)) msg << "CoverageParams.minRegionMm2 must be >= 0, got " << p.minRegionMm2;
    else return;
    throw ParameterError(msg.str());
}

/// Seen area, fraction and missed regions of one method from its per-triangle marks.
void summarise(MethodCoverage& m, const RayScene::Impl& im, const VertexTriangles& vt, const TriangleGeometry& geo,
               double totalArea, const Centerline& line, const CenterlineLocator& locator, double minRegionMm2,
               std::vector<std::vector<uint32_t>>* regionTriangles = nullptr)
{
    const std::size_t nf = geo.areaMm2.size();
    m.seenAreaMm2 = 0;
    for (std::size_t f = 0; f < nf; ++f)
        if (m.seen[f]) m.seenAreaMm2 += geo.areaMm2[f];
    m.fraction = totalArea > 0 ? m.seenAreaMm2 / totalArea : 0.0;

    // Edge-connected components of unseen triangles (iterative flood fill).
    std::vector<uint8_t> visited(nf, 0);
    std::vector<int> stack;
    std::vector<uint32_t> members;
    std::vector<std::vector<uint32_t>> regionMembers;
    m.missed.clear();
    m.missedInListedRegionsMm2 = 0;
    for (std::size_t f0 = 0; f0 < nf; ++f0) {
        if (m.seen[f0] || visited[f0]) continue;
        MissedRegion r;
        Vec3d weighted{0, 0, 0};
        visited[f0] = 1;
        stack.assign(1, int(f0));
        members.clear();
        while (!stack.empty()) {
            const int f = stack.back();
            stack.pop_back();
            if (regionTriangles) members.push_back(uint32_t(f));
            r.areaMm2 += geo.areaMm2[std::size_t(f)];
            weighted += geo.centroidMm[std::size_t(f)] * geo.areaMm2[std::size_t(f)];
            ++r.triangles;
            // Edge neighbours: triangles sharing two vertices with f.
            const uint32_t* t = &im.indices[3 * std::size_t(f)];
            for (int e = 0; e < 3; ++e) {
                const uint32_t a = t[e], b = t[(e + 1) % 3];
                for (uint32_t k = vt.start[a]; k < vt.start[a + 1]; ++k) {
                    const uint32_t g = vt.list[k];
                    if (g == uint32_t(f) || m.seen[g] || visited[g]) continue;
                    const uint32_t* u = &im.indices[3 * std::size_t(g)];
                    if (u[0] == b || u[1] == b || u[2] == b) {
                        visited[g] = 1;
                        stack.push_back(int(g));
                    }
                }
            }
        }
        if (r.areaMm2 < minRegionMm2 || !(r.areaMm2 > 0)) continue;
        r.centroidMm = weighted / r.areaMm2;
        r.nearestCenterlineIndex = locator.nearest(r.centroidMm);
        r.arcMm = double(r.nearestCenterlineIndex) * line.stepMm;
        r.distanceToCenterlineMm = distance(r.centroidMm, line.points[r.nearestCenterlineIndex].positionMm);
        m.missedInListedRegionsMm2 += r.areaMm2;
        m.missed.push_back(r);
        if (regionTriangles) regionMembers.push_back(members);
    }
    // Largest first (ties in discovery order, so the result does not depend on the sort).
    std::vector<std::size_t> order(m.missed.size());
    for (std::size_t k = 0; k < order.size(); ++k) order[k] = k;
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return m.missed[a].areaMm2 > m.missed[b].areaMm2; });
    std::vector<MissedRegion> sorted;
    sorted.reserve(order.size());
    for (const std::size_t k : order) sorted.push_back(m.missed[k]);
    m.missed.swap(sorted);
    if (regionTriangles) {
        regionTriangles->clear();
        for (const std::size_t k : order) regionTriangles->push_back(std::move(regionMembers[k]));
    }
}

} // namespace

TriangleGeometry triangleGeometry(const RayScene& scene, const Centerline* centerline)
{
    const RayScene::Impl& im = scene.impl();
    TriangleGeometry g;
    g.areaMm2.resize(im.triangles);
    g.centroidMm.resize(im.triangles);
    for (uint32_t f = 0; f < im.triangles; ++f) {
        Vec3d c[3];
        for (int k = 0; k < 3; ++k) {
            const auto& v = im.vertices[im.indices[3 * std::size_t(f) + std::size_t(k)]];
            c[k] = {v.x, v.y, v.z};
        }
        g.areaMm2[f] = 0.5 * length(cross(c[1] - c[0], c[2] - c[0]));
        g.centroidMm[f] = (c[0] + c[1] + c[2]) / 3.0;
    }
    if (!centerline || centerline->leftOutBranchMm.empty() || centerline->points.empty()) return g;
    // The branch's wall: nearer to its axis than to the path, within three of its radii.
    const std::vector<Vec3d>& axis = centerline->leftOutBranchMm;
    const double reach = 3.0 * std::max(centerline->leftOutBranchRadiusMm, 1.0);
    Vec3d lo = axis.front(), hi = axis.front();
    for (const Vec3d& a : axis)
        for (int c = 0; c < 3; ++c) {
            lo[c] = std::min(lo[c], a[c] - reach);
            hi[c] = std::max(hi[c], a[c] + reach);
        }
    const CenterlineLocator locator(*centerline);
    for (uint32_t f = 0; f < im.triangles; ++f) {
        const Vec3d& p = g.centroidMm[f];
        if (p.x < lo.x || p.y < lo.y || p.z < lo.z || p.x > hi.x || p.y > hi.y || p.z > hi.z) continue;
        double toBranch = std::numeric_limits<double>::infinity();
        for (std::size_t i = 0; i < axis.size(); ++i)
            toBranch = std::min(toBranch, distanceToSegment(p, axis[i], axis[std::min(i + 1, axis.size() - 1)]));
        if (toBranch > reach) continue;
        if (toBranch < distance(p, centerline->points[locator.nearest(p)].positionMm)) {
            g.leftOutAreaMm2 += g.areaMm2[f];
            g.areaMm2[f] = 0.0;
        }
    }
    return g;
}

CenterlineLocator::CenterlineLocator(const Centerline& centerline, double cellMm)
    : mLine(centerline), mCell(cellMm)
{
    if (centerline.points.empty()) throw InputError("CenterlineLocator: the centerline is empty");
    if (!(cellMm > 0)) throw ParameterError("CenterlineLocator: cellMm must be > 0");
    constexpr double INF = std::numeric_limits<double>::infinity();
    Vec3d lo{INF, INF, INF}, hi{-INF, -INF, -INF};
    for (const auto& p : centerline.points)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], p.positionMm[a]);
            hi[a] = std::max(hi[a], p.positionMm[a]);
        }
    mOrigin = lo;
    for (int a = 0; a < 3; ++a) {
        mDims[a] = int64_t(std::floor((hi[a] - lo[a]) / mCell)) + 1;
        mMaxRing = std::max(mMaxRing, mDims[a]);
    }
    for (std::size_t i = 0; i < centerline.points.size(); ++i) {
        const Vec3d& p = centerline.points[i].positionMm;
        const int64_t c[3] = {int64_t((p.x - lo.x) / mCell), int64_t((p.y - lo.y) / mCell),
                              int64_t((p.z - lo.z) / mCell)};
        mCells[key(c[0], c[1], c[2])].push_back(i);
    }
}

int64_t CenterlineLocator::key(int64_t i, int64_t j, int64_t k) const { return i + mDims[0] * (j + mDims[1] * k); }

std::size_t CenterlineLocator::nearest(const Vec3d& q) const
{
    // Rings of cells around the query's cell, nearest first: after ring r every point not yet
    // seen lies in a cell at least r cells away, hence at least r * cell from the query.
    int64_t qc[3];
    for (int a = 0; a < 3; ++a) qc[a] = int64_t(std::floor((q[a] - mOrigin[a]) / mCell));
    // A query far outside the grid starts at the first ring that reaches the grid.
    int64_t start = 0;
    for (int a = 0; a < 3; ++a)
        start = std::max(start, std::max(-qc[a], qc[a] - (mDims[a] - 1)));
    double best = std::numeric_limits<double>::infinity();
    std::size_t bestIndex = 0;
    const int64_t lastRing = start + mMaxRing;
    for (int64_t r = start; r <= lastRing; ++r) {
        const int64_t i0 = std::max<int64_t>(0, qc[0] - r), i1 = std::min(mDims[0] - 1, qc[0] + r);
        const int64_t j0 = std::max<int64_t>(0, qc[1] - r), j1 = std::min(mDims[1] - 1, qc[1] + r);
        const int64_t k0 = std::max<int64_t>(0, qc[2] - r), k1 = std::min(mDims[2] - 1, qc[2] + r);
        for (int64_t k = k0; k <= k1; ++k)
            for (int64_t j = j0; j <= j1; ++j)
                for (int64_t i = i0; i <= i1; ++i) {
                    const int64_t ring =
                        std::max({std::abs(i - qc[0]), std::abs(j - qc[1]), std::abs(k - qc[2])});
                    if (ring != r) continue;
                    const auto it = mCells.find(key(i, j, k));
                    if (it == mCells.end()) continue;
                    for (const std::size_t idx : it->second) {
                        const double d = distance(q, mLine.points[idx].positionMm);
                        if (d < best || (d == best && idx < bestIndex)) {
                            best = d;
                            bestIndex = idx;
                        }
                    }
                }
        if (best <= double(r) * mCell) break;
    }
    return bestIndex;
}

/// Per-marker scratch: the hit image and the footprint walk's state.
struct ViewMarker::Scratch {
    HitImage hits;
    std::vector<uint32_t> stamp;  ///< BFS visit marks, one stamp value per ray
    uint32_t currentStamp = 0;
    std::vector<uint32_t> queue;
    std::vector<double> columnFactor, rowFactor;  ///< pixelDirection's per-column / per-row terms
};

ViewMarker::ViewMarker(const RayScene& scene, int viewPx, bool footprint)
    : mScene(scene), mViewPx(viewPx), mFootprint(footprint)
{
    if (!(viewPx >= 8 && viewPx <= 4096))
        throw ParameterError("ViewMarker: viewPx must be in 8..4096, got " + std::to_string(viewPx));
    mTopology = std::make_shared<const Topology>(scene.impl());
    mScratch = std::make_unique<Scratch>();
}

ViewMarker::ViewMarker(const ViewMarker& other)
    : mScene(other.mScene), mViewPx(other.mViewPx), mFootprint(other.mFootprint), mTopology(other.mTopology),
      mScratch(std::make_unique<Scratch>())
{
}

ViewMarker::~ViewMarker() = default;

uint64_t ViewMarker::mark(const Camera& camera, bool ost, std::vector<uint32_t>& out, const LoopWindow& loop)
{
    return markWith(camera, ost, loop, [&](const uint32_t* begin, const uint32_t* end) { out.insert(out.end(), begin, end); });
}

uint64_t ViewMarker::mark(const Camera& camera, bool ost, uint8_t* seen, const LoopWindow& loop)
{
    return markWith(camera, ost, loop, [seen](const uint32_t* begin, const uint32_t* end) {
        for (const uint32_t* f = begin; f != end; ++f) seen[*f] = 1;
    });
}

template <typename Shown>
uint64_t ViewMarker::markWith(const Camera& camera, bool ost, const LoopWindow& loop, const Shown& shown)
{
    const RayScene::Impl& im = mScene.impl();
    const Topology& vt = *mTopology;
    const std::size_t nf = im.triangles;
    Scratch& w = *mScratch;
    if (w.stamp.size() != nf) w.stamp.assign(nf, 0);
    auto vertexOf = [&](uint32_t f, int k) {
        const auto& v = im.vertices[im.indices[3 * std::size_t(f) + std::size_t(k)]];
        return Vec3d{v.x, v.y, v.z};
    };
    RenderOptions o;
    o.widthPx = o.heightPx = mViewPx;
    o.ost = ost;
    o.loop = loop;
    HitImage& hits = w.hits;
    traceHits(mScene, camera, o, hits);
    // Lateral distance between neighbouring rays at depth 1 (dot(dir, forward) == 1).
    const double spacingAtUnitDepth =
        2.0 * std::tan(0.5 * camera.fovDeg * 3.14159265358979323846 / 180.0) / double(mViewPx);
    // pixelDirection(camera, w, h, x + 0.5, y + 0.5) term by term, with its tangent and the
    // per-column and per-row factors computed once per view (the same double arithmetic).
    const double tanHalf = std::tan(0.5 * (camera.fovDeg * 3.14159265358979323846 / 180.0));
    const double aspect = double(hits.width) / double(hits.height);
    w.columnFactor.resize(std::size_t(hits.width));
    w.rowFactor.resize(std::size_t(hits.height));
    for (int x = 0; x < hits.width; ++x)
        w.columnFactor[std::size_t(x)] = (2.0 * (x + 0.5) / hits.width - 1.0) * tanHalf * aspect;
    for (int y = 0; y < hits.height; ++y)
        w.rowFactor[std::size_t(y)] = (1.0 - 2.0 * (y + 0.5) / hits.height) * tanHalf;
    for (int y = 0; y < hits.height; ++y)
        for (int x = 0; x < hits.width; ++x) {
            const std::size_t pix = std::size_t(y) * std::size_t(hits.width) + std::size_t(x);
            const uint32_t id = hits.primId[pix];
            if (id >= nf) continue;
            if (!mFootprint) {
                shown(&id, &id + 1);
                continue;
            }
            // The ray's footprint: the surface within half the ray spacing of the hit,
            // stretched by 1/cos of the incidence (capped at 4x), walked over edge
            // neighbours that face the camera.
            const Vec3d dir = camera.forward + camera.right * w.columnFactor[std::size_t(x)] +
                              camera.up * w.rowFactor[std::size_t(y)];
            const Vec3d hit = camera.position + dir * double(hits.t[pix]);
            const Vec3d ng = normalize(cross(vertexOf(id, 1) - vertexOf(id, 0), vertexOf(id, 2) - vertexOf(id, 0)));
            const double cosine = std::fabs(dot(normalize(dir), ng));
            const double radius = 0.5 * spacingAtUnitDepth * double(hits.t[pix]) / std::max(cosine, 0.25);
            const double r2 = radius * radius;
            if (++w.currentStamp == 0) {  // wrapped: clear the marks once every 2^32 rays
                std::fill(w.stamp.begin(), w.stamp.end(), 0u);
                w.currentStamp = 1;
            }
            const uint32_t current = w.currentStamp;
            uint32_t* stamp = w.stamp.data();
            stamp[id] = current;
            // The walk's queue is the ray's triangles in the order found. A neighbour that
            // passes is written at its end, which advances only then: no branch on the
            // facing and nearness tests, whose outcomes are unpredictable.
            std::size_t tail = 1;
            if (w.queue.size() < 64) w.queue.resize(64);
            w.queue[0] = id;
            for (std::size_t q = 0; q < tail; ++q) {
                const uint32_t f = w.queue[q];
                const uint32_t kBegin = vt.neighbourStart[f], kEnd = vt.neighbourStart[f + 1];
                if (tail + (kEnd - kBegin) > w.queue.size()) w.queue.resize(2 * (tail + (kEnd - kBegin)));
                uint32_t* queue = w.queue.data();
                for (uint32_t k = kBegin; k < kEnd; ++k) {
                    const uint32_t g = vt.neighbours[k];
                    if (stamp[g] == current) continue;
                    stamp[g] = current;
                    const Vec3d c0 = vertexOf(g, 0), c1 = vertexOf(g, 1), c2 = vertexOf(g, 2);
                    const bool facing = !ost || dot(c0 - camera.position, cross(c1 - c0, c2 - c0)) < 0.0;
                    const Vec3d d0 = c0 - hit, d1 = c1 - hit, d2 = c2 - hit;
                    const bool near = std::min({dot(d0, d0), dot(d1, d1), dot(d2, d2)}) <= r2;
                    queue[tail] = g;
                    tail += std::size_t(facing & near);
                }
            }
            shown(w.queue.data(), w.queue.data() + tail);  // the hit triangle and those reached
        }
    return uint64_t(mViewPx) * uint64_t(mViewPx);
}

void summariseCoverage(MethodCoverage& m, const RayScene& scene, const Centerline& centerline, double minRegionMm2,
                       std::vector<std::vector<uint32_t>>* regionTriangles)
{
    if (m.seen.size() != scene.triangleCount())
        throw ParameterError("summariseCoverage: " + std::to_string(m.seen.size()) + " seen flags for " +
                             std::to_string(scene.triangleCount()) + " triangles");
    const TriangleGeometry geo = triangleGeometry(scene, &centerline);
    double total = 0;
    for (const double a : geo.areaMm2) total += a;
    const VertexTriangles vt(scene.impl(), false);  // summarise walks vertex rows only
    const CenterlineLocator locator(centerline);
    summarise(m, scene.impl(), vt, geo, total, centerline, locator, minRegionMm2, regionTriangles);
}

CoverageResult computeCoverage(const RayScene& scene, const Centerline& centerline, const CoverageParams& params,
                               Progress* progress)
{
    validate(params);
    if (centerline.points.empty()) throw InputError("computeCoverage: the centerline is empty");
    if (!params.frameRadiiMm.empty() && params.frameRadiiMm.size() != centerline.points.size())
        throw ParameterError("CoverageParams.frameRadiiMm has " + std::to_string(params.frameRadiiMm.size()) +
                             " values for " + std::to_string(centerline.points.size()) + " centerline points");
    const TriangleGeometry geo = triangleGeometry(scene, &centerline);
    const std::size_t nf = geo.areaMm2.size();

    CoverageResult result;
    for (const double a : geo.areaMm2) result.totalAreaMm2 += a;
    result.leftOutAreaMm2 = geo.leftOutAreaMm2;
    for (MethodCoverage* m : {&result.flyover, &result.flythroughForward, &result.flythroughBackward})
        m->seen.assign(nf, 0);

    // Views every stepMm of arc length (at least every point's worth), always including the last.
    const double clStep = centerline.stepMm > 0 ? centerline.stepMm : 1.0;
    const std::size_t stride = std::max<std::size_t>(1, std::size_t(std::llround(params.stepMm / clStep)));
    std::vector<std::size_t> positions;
    for (std::size_t i = 0; i < centerline.points.size(); i += stride) positions.push_back(i);
    if (positions.back() != centerline.points.size() - 1) positions.push_back(centerline.points.size() - 1);
    result.positions = positions.size();

    // Positions are marked in parallel; each worker has its own marker (hit image, BFS state)
    // and seen flags (OR-ed at the end), so no two threads write the same byte. A worker is lent
    // to one position at a time (ObjectPool): a thread waiting for a view's ray tiles may take
    // up another position meanwhile, which then gets another worker.
    const ViewMarker prototype(scene, params.viewPx, params.footprint);
    struct Worker {
        ViewMarker marker;
        std::vector<uint8_t> seen[3];  // fly-over, fly-through forward, backward
        uint64_t rays = 0;
    };
    ObjectPool<Worker> workers([&] {
        Worker w{prototype, {}, 0};
        for (auto& s : w.seen) s.assign(nf, 0);
        return w;
    });
    auto mark = [&](Worker& w, const Camera& camera, bool ost, std::vector<uint8_t>& seen, const LoopWindow& loop = {}) {
        w.rays += w.marker.mark(camera, ost, seen.data(), loop);
    };
    const std::vector<double> frameRadii = params.frameRadiiMm.empty()
                                               ? flyoverFrameRadii(scene, centerline, params.flyover)
                                               : params.frameRadiiMm;
    std::atomic<std::size_t> done{0};
    tbb::parallel_for(std::size_t(0), positions.size(), [&](std::size_t k) {
        const auto lease = workers.take();
        Worker& w = *lease;
        const CenterlinePoint& p = centerline.points[positions[k]];
        const LoopWindow loop = params.loopAt(positions[k], clStep);
        for (const Camera& c : flyoverCameras(p, params.flyover, frameRadii[positions[k]]))
            mark(w, c, params.ost, w.seen[0], loop);
        // Fly-through cameras sit inside the lumen, where OST and plain rays agree.
        if (params.flythrough) {
            mark(w, flythroughCamera(p, true, params.flythroughFovDeg), params.ost, w.seen[1]);
            mark(w, flythroughCamera(p, false, params.flythroughFovDeg), params.ost, w.seen[2]);
        }
        const std::size_t n = ++done;
        if (n % 16 == 0) reportProgress(progress, 0.95 * double(n) / double(positions.size()), "coverage rays");
    });
    MethodCoverage* methods[3] = {&result.flyover, &result.flythroughForward, &result.flythroughBackward};
    workers.forEach([&](const Worker& w) {
        result.rays += w.rays;
        for (int m = 0; m < 3; ++m)
            for (std::size_t f = 0; f < nf; ++f) methods[m]->seen[f] |= w.seen[m][f];
    });
    result.flythroughTwoWay.seen.resize(nf);
    for (std::size_t f = 0; f < nf; ++f)
        result.flythroughTwoWay.seen[f] = uint8_t(result.flythroughForward.seen[f] | result.flythroughBackward.seen[f]);

    const CenterlineLocator locator(centerline);
    for (MethodCoverage* m :
         {&result.flyover, &result.flythroughForward, &result.flythroughBackward, &result.flythroughTwoWay})
        summarise(*m, scene.impl(), prototype.topology(), geo, result.totalAreaMm2, centerline, locator,
                  params.minRegionMm2);
    reportProgress(progress, 1.0, "coverage");
    return result;
}

} // namespace flyover
