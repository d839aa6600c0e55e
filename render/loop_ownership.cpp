#include "render/loop_ownership.h"

#include "render/ray_scene_impl.h"
#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <cmath>
#include <limits>
#include <unordered_map>

namespace flyover {

namespace {

constexpr double STRETCH_MM = 10.0;      ///< one candidate point per stretch of this much arc
constexpr double SAMPLE_MM = 2.0;        ///< path points sampled this far apart for candidates
constexpr int MAX_STRETCHES = 8;         ///< stretches tried per triangle, nearest first
constexpr double SLACK_MM = 60.0;        ///< stretches farther than nearest + this are not tried
constexpr double GROUP_CELL_MM = 4.0;    ///< triangles grouped by centroid cell for candidates
constexpr float NO_OWNER = std::numeric_limits<float>::quiet_NaN();

struct PointCandidate {
    float d2;
    uint32_t point;  ///< index into the sampled path points
};

/// The sampled path points' positions and arcs.
struct PathSamples {
    std::vector<Vec3d> position;
    std::vector<float> arcMm;
    std::vector<uint32_t> stretch;  ///< arc / STRETCH_MM
    uint32_t stretches = 0;
};

PathSamples samplePath(const Centerline& cl)
{
    PathSamples s;
    const double step = cl.stepMm > 0 ? cl.stepMm : 1.0;
    const std::size_t every = std::max<std::size_t>(1, std::size_t(std::lround(SAMPLE_MM / step)));
    for (std::size_t i = 0; i < cl.points.size(); i += every) {
        const double arc = double(i) * step;
        s.position.push_back(cl.points[i].positionMm);
        s.arcMm.push_back(float(arc));
        s.stretch.push_back(uint32_t(arc / STRETCH_MM));
    }
    s.stretches = s.stretch.back() + 1;
    return s;
}

/// For a group of triangles round `centre`: the nearest sampled point of each stretch, the
/// MAX_STRETCHES nearest stretches within SLACK_MM of the nearest, nearest first.
std::vector<PointCandidate> groupCandidates(const PathSamples& s, const Vec3d& centre)
{
    std::vector<PointCandidate> best(s.stretches, PointCandidate{std::numeric_limits<float>::infinity(), 0});
    for (uint32_t i = 0; i < s.position.size(); ++i) {
        const Vec3d d = s.position[i] - centre;
        const float d2 = float(dot(d, d));
        PointCandidate& b = best[s.stretch[i]];
        if (d2 < b.d2) b = PointCandidate{d2, i};
    }
    const auto last = std::remove_if(best.begin(), best.end(), [](const PointCandidate& c) { return !std::isfinite(c.d2); });
    best.erase(last, best.end());
    const std::size_t keep = std::min<std::size_t>(MAX_STRETCHES, best.size());
    std::partial_sort(best.begin(), best.begin() + std::ptrdiff_t(keep), best.end(),
                      [](const PointCandidate& a, const PointCandidate& b) { return a.d2 < b.d2 || (a.d2 == b.d2 && a.point < b.point); });
    best.resize(keep);
    if (!best.empty()) {
        const float limit = std::sqrt(best.front().d2) + float(SLACK_MM);
        best.erase(std::remove_if(best.begin(), best.end(), [&](const PointCandidate& c) { return c.d2 > limit * limit; }),
                   best.end());
    }
    return best;
}

/// Occlusion rays from `from` to the centroids of `tris` (at most 16), 16 at a time: clear[k]
/// is set when nothing lies between (the segment's last 0.05 mm excepted, where the triangle
/// itself and its neighbours are).
void clearSights(RTCScene scene, const Vec3d& from, const Vec3d* to, int n, bool* clear)
{
    RTCIntersectContext context;
    initIntersectContext(context, false, true);
    RTCRay16 rays;
    alignas(64) int valid[16];
    for (int k = 0; k < 16; ++k) {
        valid[k] = 0;
        rays.org_x[k] = float(from.x);
        rays.org_y[k] = float(from.y);
        rays.org_z[k] = float(from.z);
        rays.dir_x[k] = rays.dir_y[k] = 0.0f;
        rays.dir_z[k] = 1.0f;
        rays.tnear[k] = 0.0f;
        rays.tfar[k] = 0.0f;
        rays.time[k] = 0.0f;
        rays.mask[k] = 0xFFFFFFFFu;
        rays.id[k] = unsigned(k);
        rays.flags[k] = 0;
        if (k >= n) continue;
        const Vec3d d = to[k] - from;
        const double len = length(d);
        clear[k] = !(len > 0.1);
        if (clear[k]) continue;
        valid[k] = -1;
        rays.dir_x[k] = float(d.x / len);
        rays.dir_y[k] = float(d.y / len);
        rays.dir_z[k] = float(d.z / len);
        rays.tfar[k] = float(len * (1.0 - 1e-4) - 0.05);
    }
    rtcOccluded16(valid, scene, &context, &rays);
    for (int k = 0; k < n; ++k)
        if (valid[k]) clear[k] = rays.tfar[k] >= 0.0f;  // Embree sets tfar to -inf when occluded
}

/// Breadth-first over triangles sharing a vertex: each triangle without an owner takes the
/// owner of the first owned triangle that reaches it. @return the triangles so owned.
std::size_t spreadOwners(const RayScene::Impl& im, std::vector<float>& owner)
{
    const std::size_t nf = im.triangles, nv = im.vertices.size();
    std::vector<uint32_t> start(nv + 1, 0), faces(3 * nf);
    for (std::size_t k = 0; k < 3 * nf; ++k) ++start[im.indices[k] + 1];
    for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (std::size_t f = 0; f < nf; ++f)
        for (int k = 0; k < 3; ++k) faces[fill[im.indices[3 * f + std::size_t(k)]]++] = uint32_t(f);
    std::vector<uint32_t> queue;
    for (std::size_t f = 0; f < nf; ++f)
        if (!std::isnan(owner[f])) queue.push_back(uint32_t(f));
    std::size_t spread = 0;
    for (std::size_t head = 0; head < queue.size(); ++head) {
        const uint32_t f = queue[head];
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = im.indices[3 * std::size_t(f) + std::size_t(k)];
            for (uint32_t e = start[v]; e < start[v + 1]; ++e) {
                const uint32_t g = faces[e];
                if (!std::isnan(owner[g])) continue;
                owner[g] = owner[f];
                queue.push_back(g);
                ++spread;
            }
        }
    }
    return spread;
}

} // namespace

TriangleOwners triangleOwners(const RayScene& scene, const Centerline& cl)
{
    if (cl.points.empty()) throw InputError("triangleOwners: the centerline is empty");
    const auto t0 = std::chrono::steady_clock::now();
    const RayScene::Impl& im = scene.impl();
    const std::size_t nf = im.triangles;
    TriangleOwners out;
    out.arcMm.assign(nf, NO_OWNER);
    const PathSamples samples = samplePath(cl);

    // Triangles grouped by the cell of their centroid: one candidate list per group.
    std::vector<Vec3d> centroid(nf), normal(nf);
    for (std::size_t f = 0; f < nf; ++f) {
        const auto& a = im.vertices[im.indices[3 * f]];
        const auto& b = im.vertices[im.indices[3 * f + 1]];
        const auto& c = im.vertices[im.indices[3 * f + 2]];
        const Vec3d pa{a.x, a.y, a.z}, pb{b.x, b.y, b.z}, pc{c.x, c.y, c.z};
        centroid[f] = (pa + pb + pc) / 3.0;
        normal[f] = cross(pb - pa, pc - pa);  // Embree's Ng: the front (lumen) side
    }
    std::unordered_map<int64_t, std::vector<uint32_t>> cells;
    auto cellKey = [](const Vec3d& p) {
        const int64_t i = int64_t(std::floor(p.x / GROUP_CELL_MM)) & 0x1FFFFF;
        const int64_t j = int64_t(std::floor(p.y / GROUP_CELL_MM)) & 0x1FFFFF;
        const int64_t k = int64_t(std::floor(p.z / GROUP_CELL_MM)) & 0x1FFFFF;
        return i | (j << 21) | (k << 42);
    };
    for (std::size_t f = 0; f < nf; ++f) cells[cellKey(centroid[f])].push_back(uint32_t(f));
    std::vector<const std::vector<uint32_t>*> groups;
    groups.reserve(cells.size());
    for (const auto& kv : cells) groups.push_back(&kv.second);

    std::vector<uint8_t> sighted(nf, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, groups.size(), 16), [&](const auto& range) {
        const DenormalsFlushed flushed;
        for (std::size_t g = range.begin(); g != range.end(); ++g) {
            const std::vector<uint32_t>& tris = *groups[g];
            Vec3d centre{0, 0, 0};
            for (const uint32_t f : tris) centre = centre + centroid[f];
            centre = centre / double(tris.size());
            const std::vector<PointCandidate> candidates = groupCandidates(samples, centre);
            // Nearest stretch first: each candidate traces to the group's triangles still
            // without an owner whose front side faces it, 16 rays from one point at a time.
            std::vector<uint32_t> pending(tris), facing, rest;
            for (const PointCandidate& c : candidates) {
                if (pending.empty()) break;
                const Vec3d& p = samples.position[c.point];
                facing.clear();
                rest.clear();
                for (const uint32_t f : pending)
                    (dot(centroid[f] - p, normal[f]) < 0.0 ? facing : rest).push_back(f);
                for (std::size_t b = 0; b < facing.size(); b += 16) {
                    const int n = int(std::min<std::size_t>(16, facing.size() - b));
                    Vec3d to[16];
                    bool clear[16];
                    for (int k = 0; k < n; ++k) to[k] = centroid[facing[b + std::size_t(k)]];
                    clearSights(im.scene, p, to, n, clear);
                    for (int k = 0; k < n; ++k) {
                        const uint32_t f = facing[b + std::size_t(k)];
                        if (!clear[k]) {
                            rest.push_back(f);
                            continue;
                        }
                        out.arcMm[f] = samples.arcMm[c.point];
                        sighted[f] = 1;
                    }
                }
                pending.swap(rest);
            }
        }
    });
    for (const uint8_t s : sighted) out.bySight += s;
    out.byNeighbour = spreadOwners(im, out.arcMm);
    out.unowned = nf - out.bySight - out.byNeighbour;
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return out;
}

namespace {

bool littleEndian()
{
    const uint16_t one = 1;
    uint8_t first = 0;
    std::memcpy(&first, &one, 1);
    return first == 1;
}

} // namespace

void writeOwners(const std::string& path, const std::vector<float>& arcMm)
{
    if (!littleEndian()) throw std::runtime_error(path + ": owners are written little-endian only");
    const std::string tmp = path + ".tmp";
    {
        std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
        out.write(reinterpret_cast<const char*>(arcMm.data()), std::streamsize(arcMm.size() * sizeof(float)));
        out.flush();
        if (!out) throw std::runtime_error(tmp + ": cannot write the triangles' owners");
    }
    std::error_code ec;
    std::filesystem::rename(tmp, path, ec);
    if (ec) throw std::runtime_error(path + ": cannot rename the owners into place: " + ec.message());
}

bool readOwners(const std::string& path, std::size_t triangles, std::vector<float>& arcMm)
{
    std::error_code ec;
    const auto bytes = std::filesystem::file_size(path, ec);
    if (ec || bytes != triangles * sizeof(float) || !littleEndian()) return false;
    std::ifstream in(path, std::ios::binary);
    std::vector<float> v(triangles);
    in.read(reinterpret_cast<char*>(v.data()), std::streamsize(bytes));
    if (!in) return false;
    for (const float a : v)
        if (std::isinf(a)) throw InputError(path + ": an owner that is infinite; remake it with --force frames");
    arcMm = std::move(v);
    return true;
}

} // namespace flyover
