// Contacts between touching loops (see contacts.h for the criterion). Steps:
//  1. lumen index (lumen_index.h), cores relative to the nearby depth;
//  2. core chunks: breadth-first shells of about chunkMm within each core piece, split into
//     connected parts;
//  3. regions: priority flood from the chunks in order of decreasing D (bucket queue);
//  4. region graph: per touching pair of regions the saddle (largest min(D, D') over the
//     26-neighbour pairs across their interface);
//  5. maximum spanning forest by relative width; the edges left out close cycles; a narrow one
//     with a long detour is a contact;
//  6. cut: the interface voxels of both regions, checked not to split the lumen; written back
//     to the grids with the distances near the cut corrected.
// Searches are serial and deterministic; scans over voxels run in parallel.
#include "volume/contacts.h"

#include "volume/error.h"
#include "volume/lumen_index.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <numeric>
#include <queue>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

namespace flyover {

namespace {

using namespace lumen_index;

/// The 13 of the 26 steps that point "backwards" (see STEPS' order): visiting only these from
/// every voxel visits each neighbouring pair once.
constexpr int HALF_STEPS = 13;

struct UnionFind {
    std::vector<int> parent;
    explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
    int find(int x)
    {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
    }
    bool unite(int a, int b)
    {
        a = find(a);
        b = find(b);
        if (a == b) return false;
        parent[std::max(a, b)] = std::min(a, b);
        return true;
    }
};

/// Two touching regions: the saddle of D across their interface.
struct Link {
    std::int32_t a = 0, b = 0;        ///< region ids, a < b
    float saddle = -1.0f;             ///< largest min(D(s), D(t)) over neighbouring s in a, t in b
    Slot sa = NO_SLOT, sb = NO_SLOT;  ///< the pair that has it
    double ratio = 0;                 ///< saddle / the smaller of the two regions' peaks
    bool tree = false;                ///< in the maximum spanning forest
};

std::uint64_t pairKey(std::int32_t a, std::int32_t b)
{
    if (a > b) std::swap(a, b);
    return (std::uint64_t(std::uint32_t(a)) << 32) | std::uint32_t(b);
}

/// Whether (saddle, sa, sb) beats the link's current saddle: larger, then lower slots.
bool better(const Link& l, float saddle, Slot sa, Slot sb)
{
    if (saddle != l.saddle) return saddle > l.saddle;
    return std::make_pair(sa, sb) < std::make_pair(l.sa, l.sb);
}

void validate(const openvdb::FloatGrid& sdf, const ContactParams& p)
{
    auto bad = [](const std::string& what) { throw ParameterError("ContactParams." + what); };
    if (!(p.maxNeckRatio > 0 && p.maxNeckRatio <= 1)) bad("maxNeckRatio must be in (0, 1]");
    if (!(p.minDetourRatio >= 1) || !std::isfinite(p.minDetourRatio))
        bad("minDetourRatio must be finite and >= 1");
    if (!(p.minDetourMm >= 0) || !std::isfinite(p.minDetourMm)) bad("minDetourMm must be finite and >= 0");
    if (!(p.chunkMm > 0) || !std::isfinite(p.chunkMm)) bad("chunkMm must be finite and > 0");
    const auto& xf = sdf.transform();
    if (!xf.isLinear()) throw InputError("cutContacts: the sdf grid's transform is not linear");
    const openvdb::Vec3d vs = xf.voxelSize();
    if (!(vs[0] > 0) || std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] || std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
        throw InputError("cutContacts: the sdf grid's voxels are not cubic");
}

/// Labels the 26-connected components of the lumen voxels with keep[s] != 0 (label -1
/// elsewhere); returns their count.
std::size_t countPieces(const LumenIndex& index, const std::vector<std::uint8_t>& removed,
                        Progress* progress)
{
    std::vector<std::uint8_t> seen(index.slotCount(), 0);
    std::vector<Slot> queue;
    std::size_t count = 0;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        if (!index.isLumen(s) || removed[s] || seen[s]) continue;
        ++count;
        queue.assign(1, s);
        seen[s] = 1;
        for (std::size_t head = 0; head < queue.size(); ++head) {
            if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
            index.forEachNeighbour(queue[head], [&](Slot t, int) {
                if (!seen[t] && !removed[t]) {
                    seen[t] = 1;
                    queue.push_back(t);
                }
            });
        }
    }
    return count;
}

} // namespace

ContactReport cutContacts(openvdb::FloatGrid& sdf, openvdb::BoolGrid* mask,
                          const ContactParams& params, Progress* progress)
{
    validate(sdf, params);
    ContactReport report;
    if (!params.enabled) return report;
    if (sdf.tree().hasActiveTiles()) sdf.tree().voxelizeActiveTiles();
    const openvdb::math::Transform& xf = sdf.transform();
    const double voxelMm = xf.voxelSize()[0];
    reportProgress(progress, 0.0, "contacts: index lumen voxels");
    const LumenIndex index = buildIndex(sdf.tree());
    const std::size_t n = index.slotCount();
    if (n == 0) return report;
    auto worldOf = [&](Slot s) {
        const openvdb::Vec3d w = xf.indexToWorld(index.coord(s));
        return Vec3d{w[0], w[1], w[2]};
    };

    // 1. Cores.
    std::vector<std::uint8_t> core(n, 0);
    {
        const std::vector<float> nearby = nearbyMaxDepth(index);
        const float minCore = static_cast<float>(voxelMm);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t s = r.begin(); s != r.end(); ++s) {
                const float d = index.depthMm[s];
                core[s] = d >= minCore && d >= 0.5f * nearby[s / LEAF_VOXELS];
            }
        });
    }
    reportProgress(progress, 0.15, "contacts: core chunks");

    // 2. Chunks: shells of breadth-first steps within each core piece, then connected parts of
    // each shell. A 26-step is up to sqrt(3) voxels long: shells count steps of ~1.2 voxels.
    std::vector<std::int32_t> region(n, -1);
    std::int32_t regionCount = 0;
    {
        std::vector<std::int32_t> shell(n, -1);
        const double shellSteps = std::max(1.0, params.chunkMm / (1.2 * voxelMm));
        std::vector<Slot> queue;
        std::vector<std::int32_t> steps(n, -1);
        for (Slot s = 0; s < n; ++s) {
            if (!core[s] || steps[s] >= 0) continue;
            queue.assign(1, s);
            steps[s] = 0;
            for (std::size_t head = 0; head < queue.size(); ++head) {
                if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
                const Slot u = queue[head];
                index.forEachNeighbour(u, [&](Slot t, int) {
                    if (core[t] && steps[t] < 0) {
                        steps[t] = steps[u] + 1;
                        queue.push_back(t);
                    }
                });
            }
        }
        for (Slot s = 0; s < n; ++s)
            if (core[s]) shell[s] = static_cast<std::int32_t>(double(steps[s]) / shellSteps);
        for (Slot s = 0; s < n; ++s) {
            if (!core[s] || region[s] >= 0) continue;
            const std::int32_t id = regionCount++;
            queue.assign(1, s);
            region[s] = id;
            for (std::size_t head = 0; head < queue.size(); ++head) {
                if ((head & 0xfffff) == 0xfffff) checkCancelled(progress);
                const Slot u = queue[head];
                index.forEachNeighbour(u, [&](Slot t, int) {
                    if (core[t] && region[t] < 0 && shell[t] == shell[u]) {
                        region[t] = id;
                        queue.push_back(t);
                    }
                });
            }
        }
    }
    reportProgress(progress, 0.3, "contacts: regions");

    // 3. Regions: priority flood by decreasing D. A voxel takes the region of the voxel that
    // reaches it first; buckets a quarter voxel wide; a voxel deeper than the current level
    // (rare: a non-core voxel behind a saddle) is processed at the current level.
    {
        float maxDepth = 0.0f;
        for (std::size_t s = 0; s < n; ++s) maxDepth = std::max(maxDepth, index.depthMm[s]);
        const double binMm = 0.25 * voxelMm;
        const int bins = static_cast<int>(maxDepth / binMm) + 1;
        auto binOf = [&](Slot s) {
            return std::min(bins - 1, static_cast<int>(double(index.depthMm[s]) / binMm));
        };
        std::vector<std::vector<Slot>> buckets(static_cast<std::size_t>(bins));
        for (Slot s = 0; s < n; ++s)
            if (region[s] >= 0) buckets[binOf(s)].push_back(s);
        std::size_t done = 0;
        for (int b = bins - 1; b >= 0; --b) {
            std::vector<Slot>& bucket = buckets[b];
            for (std::size_t i = 0; i < bucket.size(); ++i) {  // grows while visited
                if ((++done & 0xfffff) == 0) checkCancelled(progress);
                const Slot u = bucket[i];
                const std::int32_t r = region[u];
                index.forEachNeighbour(u, [&](Slot t, int) {
                    if (region[t] < 0) {
                        region[t] = r;
                        buckets[std::min(b, binOf(t))].push_back(t);
                    }
                });
            }
            std::vector<Slot>().swap(bucket);
        }
        // Pieces without any core voxel (too thin everywhere): one region each.
        std::vector<Slot> queue;
        for (Slot s = 0; s < n; ++s) {
            if (!index.isLumen(s) || region[s] >= 0) continue;
            const std::int32_t id = regionCount++;
            queue.assign(1, s);
            region[s] = id;
            for (std::size_t head = 0; head < queue.size(); ++head)
                index.forEachNeighbour(queue[head], [&](Slot t, int) {
                    if (region[t] < 0) {
                        region[t] = id;
                        queue.push_back(t);
                    }
                });
        }
    }
    report.regions = static_cast<std::size_t>(regionCount);
    std::vector<float> peak(regionCount, -1.0f);
    std::vector<Slot> peakSlot(regionCount, NO_SLOT);
    for (Slot s = 0; s < n; ++s) {
        const std::int32_t r = region[s];
        if (r >= 0 && index.depthMm[s] > peak[r]) {
            peak[r] = index.depthMm[s];
            peakSlot[r] = s;
        }
    }
    reportProgress(progress, 0.5, "contacts: region graph");

    // 4. Links between touching regions.
    std::vector<Link> links;
    {
        using Map = std::unordered_map<std::uint64_t, Link>;
        tbb::enumerable_thread_specific<Map> local;
        const std::size_t blocks = index.blockOrigin.size();
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 16),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            Map& map = local.local();
            for (std::size_t blk = r.begin(); blk != r.end(); ++blk)
                for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s) {
                    if (!index.isLumen(s)) continue;
                    const std::int32_t rs = region[s];
                    index.forEachNeighbour(s, [&](Slot t, int k) {
                        const std::int32_t rt = region[t];
                        if (k >= HALF_STEPS || rt == rs) return;
                        const float saddle = std::min(index.depthMm[s], index.depthMm[t]);
                        const Slot sa = rs < rt ? s : t, sb = rs < rt ? t : s;
                        Link& l = map[pairKey(rs, rt)];
                        if (l.sa == NO_SLOT) {
                            l.a = std::min(rs, rt);
                            l.b = std::max(rs, rt);
                        }
                        if (better(l, saddle, sa, sb)) {
                            l.saddle = saddle;
                            l.sa = sa;
                            l.sb = sb;
                        }
                    });
                }
        });
        Map all;
        for (const Map& m : local)
            for (const auto& [key, l] : m) {
                auto [it, inserted] = all.emplace(key, l);
                if (!inserted && better(it->second, l.saddle, l.sa, l.sb)) it->second = l;
            }
        links.reserve(all.size());
        for (const auto& kv : all) links.push_back(kv.second);
    }
    for (Link& l : links)
        l.ratio = double(l.saddle) / std::max(1e-6, double(std::min(peak[l.a], peak[l.b])));
    std::sort(links.begin(), links.end(), [](const Link& x, const Link& y) {
        if (x.ratio != y.ratio) return x.ratio > y.ratio;
        return std::make_pair(x.a, x.b) < std::make_pair(y.a, y.b);
    });
    report.links = links.size();

    // 5. Maximum spanning forest; the links left out close cycles.
    {
        UnionFind uf(static_cast<std::size_t>(regionCount));
        for (Link& l : links) l.tree = uf.unite(l.a, l.b);
        std::size_t pieces = 0;
        for (std::int32_t r = 0; r < regionCount; ++r) pieces += uf.find(r) == r;
        report.pieces = pieces;
    }
    std::vector<Vec3d> nodeMm(regionCount);
    for (std::int32_t r = 0; r < regionCount; ++r) nodeMm[r] = worldOf(peakSlot[r]);
    auto narrow = [&](const Link& l) { return !l.tree && l.ratio < params.maxNeckRatio; };
    // The graph for detours: every link but the narrow cycle-closing ones.
    std::vector<std::vector<std::pair<std::int32_t, double>>> adjacency(regionCount);
    for (const Link& l : links)
        if (!narrow(l)) {
            const double len = distance(nodeMm[l.a], nodeMm[l.b]);
            adjacency[l.a].push_back({l.b, len});
            adjacency[l.b].push_back({l.a, len});
        }
    auto detourMm = [&](const Link& skip) {
        std::vector<double> dist(regionCount, std::numeric_limits<double>::infinity());
        using Entry = std::pair<double, std::int32_t>;
        std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> heap;
        dist[skip.a] = 0;
        heap.push({0.0, skip.a});
        while (!heap.empty()) {
            const auto [d, u] = heap.top();
            heap.pop();
            if (d > dist[u]) continue;
            if (u == skip.b) return d;
            for (const auto& [v, len] : adjacency[u]) {
                if ((u == skip.a && v == skip.b) || (u == skip.b && v == skip.a)) continue;
                if (d + len < dist[v]) {
                    dist[v] = d + len;
                    heap.push({d + len, v});
                }
            }
        }
        return std::numeric_limits<double>::infinity();
    };
    std::vector<const Link*> toCut;
    for (const Link& l : links) {
        if (l.tree) continue;
        ++report.cycleLinks;
        const double straight = distance(nodeMm[l.a], nodeMm[l.b]);
        const double detour = detourMm(l);
        const bool loop = detour >= params.minDetourRatio * straight && detour >= straight + params.minDetourMm;
        if (!loop) continue;  // a small cycle of regions meeting three at a time, or a pocket
        if (!narrow(l)) {
            ++report.wideCycles;
            continue;
        }
        ContactInfo c;
        c.positionMm = (worldOf(l.sa) + worldOf(l.sb)) * 0.5;
        c.widthMm = 2.0 * double(l.saddle);
        c.sideMm[0] = nodeMm[l.a];
        c.sideMm[1] = nodeMm[l.b];
        c.sideRadiusMm[0] = peak[l.a];
        c.sideRadiusMm[1] = peak[l.b];
        c.straightMm = straight;
        c.detourMm = detour;
        c.cut = true;
        c.reason = "narrowest link of a cycle through the lumen: a contact between loops";
        toCut.push_back(&l);
        report.contacts.push_back(c);
    }
    reportProgress(progress, 0.7, "contacts: cut");

    // 6. Cut: the interface voxels of each contact's two regions.
    if (!toCut.empty()) {
        std::unordered_map<std::uint64_t, int> cutIndex;  // pair -> index into toCut
        for (std::size_t i = 0; i < toCut.size(); ++i)
            cutIndex[pairKey(toCut[i]->a, toCut[i]->b)] = static_cast<int>(i);
        std::vector<std::int16_t> cutOf(n, -1);  // per slot: which cut removes it
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t s = r.begin(); s != r.end(); ++s) {
                if (!index.isLumen(static_cast<Slot>(s))) continue;
                const std::int32_t rs = region[s];
                index.forEachNeighbour(static_cast<Slot>(s), [&](Slot t, int) {
                    const std::int32_t rt = region[t];
                    if (rt == rs || cutOf[s] >= 0) return;
                    auto it = cutIndex.find(pairKey(rs, rt));
                    if (it != cutIndex.end()) cutOf[s] = static_cast<std::int16_t>(it->second);
                });
            }
        });
        std::vector<std::uint8_t> removed(n, 0), active(toCut.size(), 1);
        for (std::size_t s = 0; s < n; ++s) removed[s] = cutOf[s] >= 0;
        if (countPieces(index, removed, progress) > report.pieces) {
            // Some cut splits the lumen (its interface voxels also carried another link): add
            // the cuts one at a time and keep those that do not.
            std::fill(removed.begin(), removed.end(), 0);
            for (std::size_t i = 0; i < toCut.size(); ++i) {
                for (std::size_t s = 0; s < n; ++s)
                    if (cutOf[s] == static_cast<int>(i)) removed[s] = 1;
                if (countPieces(index, removed, progress) > report.pieces) {
                    active[i] = 0;
                    for (std::size_t s = 0; s < n; ++s)
                        if (cutOf[s] == static_cast<int>(i)) removed[s] = 0;
                }
            }
        }
        std::vector<std::vector<Coord>> voxels(toCut.size());
        for (std::size_t s = 0; s < n; ++s)
            if (removed[s]) voxels[cutOf[s]].push_back(index.coord(static_cast<Slot>(s)));

        openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(sdf.tree());
        const float half = static_cast<float>(0.5 * voxelMm);
        std::size_t c = 0;
        for (std::size_t i = 0; i < toCut.size(); ++i) {
            while (!report.contacts[c].cut) ++c;  // cut ones are in toCut's order
            ContactInfo& info = report.contacts[c++];
            if (!active[i]) {
                info.cut = false;
                info.reason = "a cycle's narrowest link whose cut would split the lumen: kept";
                continue;
            }
            info.voxelsRemoved = voxels[i].size();
            for (const Coord& v : voxels[i]) {
                acc.setValueOn(v, half);
                if (mask) mask->tree().setValueOff(v, false);
            }
            // Distances near the cut: within the deeper side's radius of a removed voxel.
            const int reach = std::min(
                32, static_cast<int>(std::ceil(std::max(info.sideRadiusMm[0], info.sideRadiusMm[1]) / voxelMm)) + 1);
            for (const Coord& v : voxels[i])
                for (int dx = -reach; dx <= reach; ++dx)
                    for (int dy = -reach; dy <= reach; ++dy)
                        for (int dz = -reach; dz <= reach; ++dz) {
                            const double r2 = double(dx * dx + dy * dy + dz * dz);
                            if (r2 == 0 || r2 > double(reach * reach)) continue;
                            const Coord q = v.offsetBy(dx, dy, dz);
                            float value;
                            if (!acc.probeValue(q, value) || !(value < 0.0f)) continue;
                            const float bound = static_cast<float>(-(std::sqrt(r2) - 0.5) * voxelMm);
                            if (bound > value) acc.setValueOnly(q, bound);
                        }
        }
        // Reported: cut contacts first, then those kept; each group narrowest first.
        std::stable_sort(report.contacts.begin(), report.contacts.end(),
                         [](const ContactInfo& x, const ContactInfo& y) {
            if (x.cut != y.cut) return x.cut;
            return x.widthMm < y.widthMm;
        });
    }
    reportProgress(progress, 1.0, "contacts done");
    return report;
}

} // namespace flyover
