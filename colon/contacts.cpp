// Contacts between touching loops (see contacts.h for the criterion). Steps:
//  1.-3. (contact_regions.h) lumen index (lumen_index.h), cores relative to the nearby depth;
//     core chunks: breadth-first shells of about chunkMm within each core piece, split into
//     connected parts; regions: priority flood from the chunks in order of decreasing D;
//  4. region graph: per touching pair of regions the saddle (largest min(D, D') over the
//     26-neighbour pairs across their interface);
//  5. maximum spanning forest by relative width; a narrow link left out (it closes a cycle) is a
//     contact when the way round through the lumen deeper than its neck is long (5a); a narrow
//     tree link is one when it meets a tube from the side on both hands (5b);
//  6. cut: the interface voxels of both regions, checked not to split the lumen more than the
//     kind of cut allows; written back to the grids with the distances near the cut corrected;
//     cuts close together reported as one contact.
// Searches are deterministic (the same result on any number of threads); scans over voxels run
// in parallel, and so do the region flood's large batches (contact_regions.h) and the ways round
// of 5a up to the first cut.
#include "colon/contacts.h"
#include "volume/vec3.h"

#include "colon/contact_regions.h"
#include "volume/threads.h"
#include "volume/error.h"
#include "colon/lumen_index.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
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

/// The distances of one search over the lumen's slots (+inf where none), held for the blocks
/// the search reaches only: a search reaches few, and searches side by side each need their own.
class SparseReach {
public:
    explicit SparseReach(std::size_t blocks) : blockOf_(blocks, -1) {}
    float get(Slot s) const
    {
        const std::int32_t b = blockOf_[s / LEAF_VOXELS];
        return b < 0 ? std::numeric_limits<float>::infinity() : pool_[std::size_t(b)][s % LEAF_VOXELS];
    }
    /// The slot's distance, to be written (+inf when first reached).
    float& at(Slot s)
    {
        std::int32_t& b = blockOf_[s / LEAF_VOXELS];
        if (b < 0) {
            b = static_cast<std::int32_t>(used_++);
            if (used_ > pool_.size()) pool_.emplace_back();
            pool_[std::size_t(b)].fill(std::numeric_limits<float>::infinity());
            reached_.push_back(s / LEAF_VOXELS);
        }
        return pool_[std::size_t(b)][s % LEAF_VOXELS];
    }
    void clear()
    {
        for (std::size_t blk : reached_) blockOf_[blk] = -1;
        reached_.clear();
        used_ = 0;
    }

private:
    std::vector<std::int32_t> blockOf_;  ///< per block: its index in pool_, or -1
    std::vector<std::array<float, LEAF_VOXELS>> pool_;
    std::vector<std::size_t> reached_;
    std::size_t used_ = 0;
};

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
    if (!(p.minArmMm >= 0) || !std::isfinite(p.minArmMm)) bad("minArmMm must be finite and >= 0");
    if (!(p.minArmRadii >= 0) || !std::isfinite(p.minArmRadii)) bad("minArmRadii must be finite and >= 0");
    const auto& xf = sdf.transform();
    if (!xf.isLinear()) throw InputError("cutContacts: the sdf grid's transform is not linear");
    const openvdb::Vec3d vs = xf.voxelSize();
    if (!(vs[0] > 0) || std::abs(vs[0] - vs[1]) > 1e-6 * vs[0] || std::abs(vs[0] - vs[2]) > 1e-6 * vs[0])
        throw InputError("cutContacts: the sdf grid's voxels are not cubic");
}

/// What the steps share: the lumen's index, its regions and the graph of touching regions.
struct RegionGraph {
    RegionGraph(const LumenIndex& i, const openvdb::math::Transform& x, double v, contact_regions::Regions r)
        : index(i), xf(x), voxelMm(v), flooded(std::move(r)) {}
    const LumenIndex& index;
    const openvdb::math::Transform& xf;
    double voxelMm = 0;
    contact_regions::Regions flooded;
    std::vector<float> peak;       ///< per region: its largest depth D
    std::vector<Slot> peakSlot;    ///< per region: the voxel with it
    std::vector<Link> links;       ///< widest (relative) first
    std::vector<Slot> boundary;    ///< voxels with a 26-neighbour in another region, in slot order
    std::vector<Vec3d> nodeMm;     ///< per region: its peak's position

    Vec3d worldOf(Slot s) const
    {
        const openvdb::Vec3d w = xf.indexToWorld(index.coord(s));
        return Vec3d{w[0], w[1], w[2]};
    }
};

bool isNarrow(const Link& l, const ContactParams& params) { return l.ratio < params.maxNeckRatio; }

/// Each region's deepest voxel.
void findPeaks(RegionGraph& g)
{
    const std::vector<std::int32_t>& region = g.flooded.region;
    g.peak.assign(g.flooded.count, -1.0f);
    g.peakSlot.assign(g.flooded.count, NO_SLOT);
    for (Slot s = 0; s < g.index.slotCount(); ++s) {
        const std::int32_t r = region[s];
        if (r >= 0 && g.index.depthMm[s] > g.peak[r]) {
            g.peak[r] = g.index.depthMm[s];
            g.peakSlot[r] = s;
        }
    }
}

/// 4. Links between touching regions; on the way, the boundary voxels (those with a
/// 26-neighbour in another region: the only ones that can lie on an interface, step 5).
/// Then each link's ratio to the smaller peak, widest first.
void linkRegions(RegionGraph& g)
{
    const LumenIndex& index = g.index;
    const std::vector<std::int32_t>& region = g.flooded.region;
    const std::size_t blocks = index.blockOrigin.size();
    std::vector<Link>& links = g.links;
    std::vector<Slot>& boundary = g.boundary;
    const std::vector<float>& peak = g.peak;
    using Map = std::unordered_map<std::uint64_t, Link>;
    tbb::enumerable_thread_specific<Map> local;
    // Per range of blocks, its boundary voxels in slot order; ranges in order at the end.
    tbb::enumerable_thread_specific<std::vector<std::pair<std::size_t, std::vector<Slot>>>> boundaryParts;
    // A block whose lumen voxels are all in one region (uniform) has no boundary voxel
    // inside (away from its faces), and none at all when its neighbour blocks are uniform
    // in the same region: those voxels are skipped (they touch no other region).
    constexpr std::int32_t MIXED = -1;
    std::vector<std::int32_t> uniform(blocks, MIXED);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t blk = r.begin(); blk != r.end(); ++blk) {
            std::int32_t only = MIXED;
            bool mixed = false;
            for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS && !mixed; ++s) {
                if (!index.isLumen(s)) continue;
                if (only == MIXED) only = region[s];
                else mixed = region[s] != only;
            }
            uniform[blk] = mixed ? MIXED : only;
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 16),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        Map& map = local.local();
        std::vector<Slot> part;
        for (std::size_t blk = r.begin(); blk != r.end(); ++blk) {
            const std::int32_t only = uniform[blk];
            if (only != MIXED) {
                bool alone = true;
                for (std::int32_t nb : index.neighbour[blk])
                    if (nb >= 0 && uniform[static_cast<std::size_t>(nb)] != only) alone = false;
                if (alone) continue;
            }
            for (Slot s = static_cast<Slot>(blk * LEAF_VOXELS); s < (blk + 1) * LEAF_VOXELS; ++s) {
                if (!index.isLumen(s)) continue;
                if (only != MIXED) {
                    const int off = static_cast<int>(s % LEAF_VOXELS);
                    const int x = off >> (2 * LEAF_LOG2), y = (off >> LEAF_LOG2) & (LEAF_DIM - 1),
                              z = off & (LEAF_DIM - 1);
                    if (x > 0 && x < LEAF_DIM - 1 && y > 0 && y < LEAF_DIM - 1 && z > 0 && z < LEAF_DIM - 1)
                        continue;
                }
                const std::int32_t rs = region[s];
                std::int32_t lastRegion = rs;  // the link of the last neighbour in another region
                Link* last = nullptr;
                bool onBoundary = false;
                // Holes hold region -1: one read of `region` tests a neighbour.
                index.forEachNeighbourSlot(s, [&](Slot t, int k) {
                    const std::int32_t rt = region[t];
                    if (rt == rs || rt < 0) return;
                    onBoundary = true;
                    if (k >= HALF_STEPS) return;
                    const float saddle = std::min(index.depthMm[s], index.depthMm[t]);
                    const Slot sa = rs < rt ? s : t, sb = rs < rt ? t : s;
                    if (rt != lastRegion) {
                        last = &map[pairKey(rs, rt)];
                        lastRegion = rt;
                    }
                    Link& l = *last;
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
                if (onBoundary) part.push_back(s);
            }
        }
        if (!part.empty()) boundaryParts.local().push_back({r.begin(), std::move(part)});
    });
    std::vector<std::pair<std::size_t, std::vector<Slot>>> parts;
    for (auto& p : boundaryParts)
        for (auto& q : p) parts.push_back(std::move(q));
    std::sort(parts.begin(), parts.end(),
              [](const auto& x, const auto& y) { return x.first < y.first; });
    std::size_t total = 0;
    for (const auto& p : parts) total += p.second.size();
    boundary.reserve(total);
    for (const auto& p : parts) boundary.insert(boundary.end(), p.second.begin(), p.second.end());
    Map all;
    for (const Map& m : local)
        for (const auto& [key, l] : m) {
            auto [it, inserted] = all.emplace(key, l);
            if (!inserted && better(it->second, l.saddle, l.sa, l.sb)) it->second = l;
        }
    links.reserve(all.size());
    for (const auto& kv : all) links.push_back(kv.second);
for (Link& l : links)
    l.ratio = double(l.saddle) / std::max(1e-6, double(std::min(peak[l.a], peak[l.b])));
std::sort(links.begin(), links.end(), [](const Link& x, const Link& y) {
    if (x.ratio != y.ratio) return x.ratio > y.ratio;
    return std::make_pair(x.a, x.b) < std::make_pair(y.a, y.b);
});
}

/// 5. Maximum spanning forest (Link::tree); the links left out close cycles. Returns the pieces.
std::size_t spanningForest(std::vector<Link>& links, std::int32_t regionCount)
{
    UnionFind<> uf(static_cast<std::size_t>(regionCount));
    for (Link& l : links) l.tree = uf.unite(l.a, l.b);
    std::size_t pieces = 0;
    for (std::int32_t r = 0; r < regionCount; ++r) pieces += uf.find(r) == r;
    return pieces;
}

/// Wide cycles (counted only): the way round through the region graph, without the narrow
/// links, is long.
void countWideCycles(const RegionGraph& g, const ContactParams& params, ContactReport& report)
{
    const std::int32_t regionCount = g.flooded.count;
    const std::vector<Link>& links = g.links;
    const std::vector<Vec3d>& nodeMm = g.nodeMm;
    auto narrow = [&](const Link& l) { return isNarrow(l, params); };
    std::vector<std::vector<std::pair<std::int32_t, double>>> adjacency(regionCount);
    for (const Link& l : links)
        if (l.tree || !narrow(l)) {
            const double len = distance(nodeMm[l.a], nodeMm[l.b]);
            adjacency[l.a].push_back({l.b, len});
            adjacency[l.b].push_back({l.a, len});
        }
    auto graphDetourMm = [&](const Link& skip) {
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
    for (const Link& l : links) {
        if (l.tree) continue;
        ++report.cycleLinks;
        if (narrow(l)) continue;
        const double straight = distance(nodeMm[l.a], nodeMm[l.b]);
        const double detour = graphDetourMm(l);
        if (detour >= params.minDetourRatio * straight && detour >= straight + params.minDetourMm)
            ++report.wideCycles;
    }
}

/// The narrow links (indices into the links) and their interface voxels.
struct NarrowLinks {
    std::vector<std::size_t> links;
    std::vector<std::vector<Slot>> interfaceOf;
};

/// The narrow links and their interface voxels (what a cut removes: the voxels of either
/// region with a 26-neighbour in the other), in slot order.
NarrowLinks narrowInterfaces(const RegionGraph& g, const ContactParams& params)
{
    const LumenIndex& index = g.index;
    const std::vector<std::int32_t>& region = g.flooded.region;
    const std::int32_t regionCount = g.flooded.count;
    const std::vector<Link>& links = g.links;
    const std::vector<Slot>& boundary = g.boundary;
    auto narrow = [&](const Link& l) { return isNarrow(l, params); };
std::vector<std::size_t> narrowLinks;
std::unordered_map<std::uint64_t, int> narrowOf;
for (std::size_t i = 0; i < links.size(); ++i)
    if (narrow(links[i])) {
        narrowOf[pairKey(links[i].a, links[i].b)] = static_cast<int>(narrowLinks.size());
        narrowLinks.push_back(i);
    }
std::vector<std::vector<Slot>> interfaceOf(narrowLinks.size());
if (!narrowLinks.empty()) {
    // Only the voxels of regions with a narrow link can be on an interface.
    std::vector<std::uint8_t> hasNarrow(static_cast<std::size_t>(regionCount), 0);
    for (std::size_t i : narrowLinks) hasNarrow[links[i].a] = hasNarrow[links[i].b] = 1;
    using Hits = std::vector<std::pair<int, Slot>>;
    tbb::enumerable_thread_specific<Hits> local;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, boundary.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        Hits& hits = local.local();
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
            const Slot s = boundary[i];
            const std::int32_t rs = region[s];
            if (!hasNarrow[rs]) continue;
            int last = -1;
            std::int32_t lastRegion = rs;  // a neighbour of the same region as the last: no new link
            index.forEachNeighbourSlot(s, [&](Slot t, int) {
                const std::int32_t rt = region[t];
                if (rt == lastRegion || rt < 0) return;  // a hole: -1
                lastRegion = rt;
                auto it = narrowOf.find(pairKey(rs, rt));
                if (it == narrowOf.end() || it->second == last) return;
                last = it->second;
                hits.push_back({it->second, s});
            });
        }
    });
    for (const Hits& hits : local)
        for (const auto& [k, s] : hits) interfaceOf[k].push_back(s);
    for (std::vector<Slot>& v : interfaceOf) {
        std::sort(v.begin(), v.end());
        v.erase(std::unique(v.begin(), v.end()), v.end());
    }
}

    return {std::move(narrowLinks), std::move(interfaceOf)};
}

/// The way round: the shortest path through the lumen from `from` to `to` over voxels
/// deeper than `above` and not removed (26-steps); +inf when longer than boundMm.
/// A* search: a voxel is taken in order of its distance from `from` plus its straight
/// distance to `to` (a lower bound of the rest of the way: every 26-step is as long as the
/// straight line between its ends), scaled down by 1e-4 so that float rounding (of sums of up to ~10^4 steps) keeps
/// it a lower bound. With a lower bound and re-opened voxels, the first time `to` is taken
/// its distance is the shortest (the same as Dijkstra's), and a voxel whose distance plus
/// bound exceeds boundMm lies on no way round shorter than boundMm; but it visits the voxels
/// towards `to` first, instead of a ball of radius boundMm around `from`.
/// `reach`: the search's own distances (searches may run side by side, each with its own).
double wayRoundMm(const LumenIndex& index, const std::vector<std::uint8_t>& removed, double voxelMm, SparseReach& reach,
                  Slot from, Slot to, float above, double boundMm, Progress* cancelWith)
{
    reach.clear();
    struct Entry {
        float f, g;  ///< g + the bound of the rest, g = the distance from `from`
        Slot s;
        bool operator>(const Entry& o) const { return f != o.f ? f > o.f : s > o.s; }
    };
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> heap;
    const Coord target = index.coord(to);
    const double boundScale = voxelMm * (1.0 - 1e-4);
    auto restMm = [&](Slot t) {
        const Coord d = index.coord(t) - target;
        return boundScale * std::sqrt(double(d.x()) * d.x() + double(d.y()) * d.y() + double(d.z()) * d.z());
    };
    reach.at(from) = 0.0f;
    heap.push({static_cast<float>(restMm(from)), 0.0f, from});
    double found = std::numeric_limits<double>::infinity();
    std::size_t pops = 0;
    while (!heap.empty()) {
        const Entry e = heap.top();
        heap.pop();
        if ((++pops & 0xfffff) == 0) checkCancelled(cancelWith);
        const float d = e.g;
        const Slot u = e.s;
        if (d > reach.get(u)) continue;
        if (u == to) {
            found = d;
            break;
        }
        index.forEachNeighbour(u, [&](Slot t, int k) {
            if (removed[t] || !(index.depthMm[t] > above)) return;
            const float nd = d + static_cast<float>(STEPS[k].lengthVoxels * voxelMm);
            if (!(nd < reach.get(t))) return;
            const double rest = restMm(t);
            if (nd + rest <= boundMm) {
                reach.at(t) = nd;
                heap.push({static_cast<float>(nd + rest), nd, t});
            }
        });
    }
    return found;
}

struct Cut {
    int narrow = 0;     ///< index into NarrowLinks::links
    bool tree = false;  ///< a tree link (no cycle): the cut adds a piece
    ContactInfo info;
};

ContactInfo contactInfo(const RegionGraph& g, const Link& l)
{
    ContactInfo c;
    c.positionMm = (g.worldOf(l.sa) + g.worldOf(l.sb)) * 0.5;
    c.widthMm = 2.0 * double(l.saddle);
    c.sideMm[0] = g.nodeMm[l.a];
    c.sideMm[1] = g.nodeMm[l.b];
    c.sideRadiusMm[0] = g.peak[l.a];
    c.sideRadiusMm[1] = g.peak[l.b];
    c.straightMm = distance(g.nodeMm[l.a], g.nodeMm[l.b]);
    c.cut = true;
    return c;
}

/// 5a. Narrow links that close a cycle, widest first (a cut one is no way round for the
/// next): a contact when the way round through the lumen deeper than the neck is long.
void cutCycleLinks(const RegionGraph& g, const NarrowLinks& narrow, const ContactParams& params,
                   std::vector<std::uint8_t>& removed, std::vector<Cut>& cuts, Progress* progress)
{
    const LumenIndex& index = g.index;
    const double voxelMm = g.voxelMm;
    const std::size_t blocks = index.blockOrigin.size();
    const std::vector<Link>& links = g.links;
    const std::vector<Slot>& peakSlot = g.peakSlot;
    const std::vector<std::size_t>& narrowLinks = narrow.links;
    const std::vector<std::vector<Slot>>& interfaceOf = narrow.interfaceOf;
    std::vector<int> order;
    for (std::size_t k = 0; k < narrowLinks.size(); ++k)
        if (!links[narrowLinks[k]].tree) order.push_back(static_cast<int>(k));
    std::stable_sort(order.begin(), order.end(), [&](int x, int y) {
        return links[narrowLinks[x]].saddle > links[narrowLinks[y]].saddle;
    });
    auto needMm = [&](const ContactInfo& c) {
        const double aroundMm = PI * std::max(c.sideRadiusMm[0], c.sideRadiusMm[1]);
        return std::max(params.minDetourRatio * c.straightMm, c.straightMm + std::max(params.minDetourMm, aroundMm));
    };
    // Until the first cut no voxel is removed: the searches up to there are those of an
    // unchanged lumen, made side by side beforehand when more than one thread may run
    // (the same searches, the same results); after a cut, each is made in turn.
    const int threads = threadsThatMayRun();
    std::vector<double> uncut;
    if (threads > 1 && order.size() > 1) {
        uncut.resize(order.size());
        tbb::enumerable_thread_specific<SparseReach> reaches([&] { return SparseReach(blocks); });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size(), 1),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            SparseReach& reach = reaches.local();
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                const Link& l = links[narrowLinks[order[i]]];
                uncut[i] = wayRoundMm(index, removed, voxelMm, reach, peakSlot[l.a], peakSlot[l.b], l.saddle,
                                      needMm(contactInfo(g, l)), nullptr);
            }
        });
        checkCancelled(progress);
    }
    SparseReach reach(blocks);
    for (std::size_t i = 0; i < order.size(); ++i) {
        const int k = order[i];
        const Link& l = links[narrowLinks[k]];
        ContactInfo c = contactInfo(g, l);
        const double need = needMm(c);
        const double way = cuts.empty() && !uncut.empty()
                               ? uncut[i]
                               : wayRoundMm(index, removed, voxelMm, reach, peakSlot[l.a], peakSlot[l.b], l.saddle,
                                            need, progress);
        if (way < need) continue;  // regions meeting around a fold, a bend or a pocket
        c.detourMm = need;  // at least
        c.reason = "narrowest link of a cycle through the lumen: a contact between loops";
        for (Slot s : interfaceOf[k]) removed[s] = 1;
        cuts.push_back({k, false, c});
    }
}

/// 5b. Narrow links of the spanning tree (no cycle: a collapse elsewhere keeps the two loops
/// apart along the colon): a contact when, on both sides, the link meets a tube from the side.
/// Per side (the tree without the link): its longest path (two farthest-point passes along
/// the tree, peaks to peaks), the point of that path nearest to the link's region, and the
/// lengths of the path on either side of it (the arms). A collapse, a stricture or a fold
/// lies across the tube: on each side it is at the end of the longest path (one arm ~0).
void cutTreeLinks(const RegionGraph& g, const NarrowLinks& narrow, const ContactParams& params,
                  std::vector<std::uint8_t>& removed, std::vector<Cut>& cuts)
{
    const std::int32_t regionCount = g.flooded.count;
    const std::vector<Link>& links = g.links;
    const std::vector<float>& peak = g.peak;
    const std::vector<Vec3d>& nodeMm = g.nodeMm;
    const std::vector<std::size_t>& narrowLinks = narrow.links;
    const std::vector<std::vector<Slot>>& interfaceOf = narrow.interfaceOf;
    std::vector<std::vector<std::pair<std::int32_t, double>>> tree(regionCount);
    for (const Link& l : links)
        if (l.tree) {
            const double len = distance(nodeMm[l.a], nodeMm[l.b]);
            tree[l.a].push_back({l.b, len});
            tree[l.b].push_back({l.a, len});
        }
    std::vector<double> fromRoot(regionCount, -1.0), fromEnd(regionCount, -1.0);
    std::vector<std::int32_t> parent(regionCount, -1);
    std::vector<std::int32_t> stack, seen;
    // Tree distances from `start` (d: all -1 before) not crossing the link (cutA, cutB);
    // `seen` gets the side's regions; returns the farthest one.
    auto sweep = [&](std::int32_t start, std::int32_t cutA, std::int32_t cutB, std::vector<double>& d) {
        seen.assign(1, start);
        stack.assign(1, start);
        d[start] = 0;
        parent[start] = -1;
        std::int32_t far = start;
        while (!stack.empty()) {
            const std::int32_t u = stack.back();
            stack.pop_back();
            if (d[u] > d[far]) far = u;
            for (const auto& [v, len] : tree[u]) {
                if ((u == cutA && v == cutB) || (u == cutB && v == cutA) || d[v] >= 0) continue;
                d[v] = d[u] + len;
                parent[v] = u;
                seen.push_back(v);
                stack.push_back(v);
            }
        }
        return far;
    };
    // The shorter arm of the side of `root` (see above), and whether the two arms leave the
    // point nearest the link the same way (`hairpin`): from that point, the path's nodes
    // about the shorter arm's length (at most two radii) along each hand lie within 90
    // degrees of each other. A tube passes a contact on its side, so its arms leave in
    // opposite directions; at a stricture the side's tube ends, and where its end holds two
    // regions across it the longest path runs up the tube to the stricture's region and
    // back down into the other one (a tube 20 mm in radius: an arm of 20 mm, over the
    // 15 mm needed).
    std::vector<std::int32_t> path;
    auto shorterArm = [&](std::int32_t root, std::int32_t other, bool& hairpin) {
        const std::int32_t e1 = sweep(root, root, other, fromRoot);
        const std::int32_t e2 = sweep(e1, root, other, fromEnd);
        // Along the longest path e2 -> e1 (the second sweep's parents lead to e1).
        path.clear();
        for (std::int32_t u = e2; u >= 0; u = parent[u]) path.push_back(u);
        double best = std::numeric_limits<double>::infinity(), arm = 0;
        std::size_t at = 0;
        for (std::size_t i = 0; i < path.size(); ++i)
            if (fromRoot[path[i]] < best) {
                best = fromRoot[path[i]];
                arm = std::min(fromEnd[path[i]], fromEnd[e2] - fromEnd[path[i]]);
                at = i;
            }
        // The node of each hand whose distance along the path from path[at] is nearest to
        // `along` (hand -1: towards e2, the path's start; +1: towards e1).
        const double along = std::min(arm, 2.0 * double(peak[path[at]]));
        auto handNode = [&](int hand) {
            std::size_t pick = at;
            double miss = std::numeric_limits<double>::infinity();
            for (std::size_t i = at;; i = hand < 0 ? i - 1 : i + 1) {
                const double d = std::abs(std::abs(fromEnd[path[i]] - fromEnd[path[at]]) - along);
                if (d < miss) {
                    miss = d;
                    pick = i;
                }
                if (hand < 0 ? i == 0 : i + 1 == path.size()) break;
            }
            return path[pick];
        };
        const Vec3d a = nodeMm[handNode(-1)] - nodeMm[path[at]];
        const Vec3d b = nodeMm[handNode(+1)] - nodeMm[path[at]];
        hairpin = length(a) > 0 && length(b) > 0 && dot(a, b) > 0;
        for (std::int32_t r : seen) fromRoot[r] = fromEnd[r] = -1.0;
        return arm;
    };
    for (std::size_t k = 0; k < narrowLinks.size(); ++k) {
        const Link& l = links[narrowLinks[k]];
        if (!l.tree) continue;
        bool hairpinA = false, hairpinB = false;
        const double armA = shorterArm(l.a, l.b, hairpinA), armB = shorterArm(l.b, l.a, hairpinB);
        const double needA = std::max(params.minArmMm, params.minArmRadii * peak[l.a]);
        const double needB = std::max(params.minArmMm, params.minArmRadii * peak[l.b]);
        if (armA < needA || armB < needB || hairpinA || hairpinB) continue;
        ContactInfo c = contactInfo(g, l);
        c.detourMm = std::numeric_limits<double>::infinity();
        c.reason = "narrow link between the sides of two tubes (no way round: a collapse lies between "
                   "them along the colon): a contact between loops";
        for (Slot s : interfaceOf[k]) removed[s] = 1;
        cuts.push_back({static_cast<int>(k), true, c});
    }
}

/// 6. Cut: check that no cut splits the lumen more than its kind allows (a tree link's cut
/// adds one piece, a cycle link's none), else add them one at a time and keep those that do
/// not; write them to the grids with the distances near them corrected.
void keepCutsThatDoNotSplit(const RegionGraph& g, const NarrowLinks& narrow, std::size_t pieces, std::vector<Cut>& cuts,
                            std::vector<std::uint8_t>& removed, Progress* progress)
{
    const LumenIndex& index = g.index;
    const contact_regions::Regions& flooded = g.flooded;
    const std::vector<Link>& links = g.links;
    const std::vector<std::vector<Slot>>& interfaceOf = narrow.interfaceOf;
    // The lumen's pieces without the removed voxels (contact_regions::piecesWithout: only
    // the regions the cuts pass through are searched voxel by voxel).
    std::vector<std::pair<std::int32_t, std::int32_t>> touching;
    touching.reserve(links.size());
    for (const Link& l : links) touching.push_back({l.a, l.b});
    auto piecesAfterCuts = [&]() {
        std::vector<Slot> removedSlots;
        for (const Cut& c : cuts)
            for (Slot s : interfaceOf[c.narrow])
                if (removed[s]) removedSlots.push_back(s);
        return contact_regions::piecesWithout(index, flooded, touching, removed, removedSlots, progress);
    };
    std::size_t treeCuts = 0;
    for (const Cut& c : cuts) treeCuts += c.tree;
    if (piecesAfterCuts() > pieces + treeCuts) {
        std::fill(removed.begin(), removed.end(), 0);
        std::size_t allowed = pieces;
        for (Cut& c : cuts) {
            std::vector<Slot> added;
            for (Slot s : interfaceOf[c.narrow])
                if (!removed[s]) {
                    removed[s] = 1;
                    added.push_back(s);
                }
            if (piecesAfterCuts() > allowed + (c.tree ? 1 : 0)) {
                for (Slot s : added) removed[s] = 0;
                c.info.cut = false;
                c.info.reason = "a contact whose cut would split the lumen further: kept";
            } else {
                allowed += c.tree ? 1 : 0;
            }
        }
    }
}

/// The voxels each kept cut removes, written to the grids (the distances near them corrected).
void writeCuts(const RegionGraph& g, const NarrowLinks& narrow, const std::vector<std::uint8_t>& removed,
               std::vector<Cut>& cuts, openvdb::FloatGrid& sdf, openvdb::BoolGrid* mask)
{
    const LumenIndex& index = g.index;
    const double voxelMm = g.voxelMm;
    const std::size_t n = index.slotCount();
    const std::vector<std::vector<Slot>>& interfaceOf = narrow.interfaceOf;
    // Each removed voxel goes to the first cut that removes it.
    std::vector<std::uint8_t> taken(n, 0);
    std::vector<std::vector<Coord>> voxels(cuts.size());
    for (std::size_t i = 0; i < cuts.size(); ++i) {
        if (!cuts[i].info.cut) continue;
        for (Slot s : interfaceOf[cuts[i].narrow])
            if (removed[s] && !taken[s]) {
                taken[s] = 1;
                voxels[i].push_back(index.coord(s));
            }
    }

    openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(sdf.tree());
    const float half = static_cast<float>(0.5 * voxelMm);
    for (std::size_t i = 0; i < cuts.size(); ++i) {
        ContactInfo& info = cuts[i].info;
        if (!info.cut) continue;
        info.voxelsRemoved = voxels[i].size();
        for (const Coord& v : voxels[i]) {
            acc.setValueOn(v, half);
            if (mask) mask->tree().setValueOff(v, false);
        }
        // Distances near the cut: within the deeper side's radius of a removed voxel.
        const int reachVoxels = std::min(
            32, static_cast<int>(std::ceil(std::max(info.sideRadiusMm[0], info.sideRadiusMm[1]) / voxelMm)) + 1);
        for (const Coord& v : voxels[i])
            for (int dx = -reachVoxels; dx <= reachVoxels; ++dx)
                for (int dy = -reachVoxels; dy <= reachVoxels; ++dy)
                    for (int dz = -reachVoxels; dz <= reachVoxels; ++dz) {
                        const double r2 = double(dx * dx + dy * dy + dz * dz);
                        if (r2 == 0 || r2 > double(reachVoxels * reachVoxels)) continue;
                        const Coord q = v.offsetBy(dx, dy, dz);
                        float value;
                        if (!acc.probeValue(q, value) || !(value < 0.0f)) continue;
                        const float bound = static_cast<float>(-(std::sqrt(r2) - 0.5) * voxelMm);
                        if (bound > value) acc.setValueOnly(q, bound);
                    }
    }
}

/// The contacts of the report from the cuts.
void reportContacts(const std::vector<Cut>& cuts, double voxelMm, ContactReport& report)
{
    // One contact per place: the links cut within the smaller lumen radius (at least three
    // voxels) of each other are one contact (a channel touching several regions on a side);
    // it is reported by its narrowest link.
    UnionFind<> same(cuts.size());
    for (std::size_t i = 0; i < cuts.size(); ++i)
        for (std::size_t j = i + 1; j < cuts.size(); ++j) {
            const ContactInfo &x = cuts[i].info, &y = cuts[j].info;
            if (x.cut != y.cut) continue;
            const double near = std::max(3.0 * voxelMm, std::min({x.sideRadiusMm[0], x.sideRadiusMm[1],
                                                                  y.sideRadiusMm[0], y.sideRadiusMm[1]}));
            if (distance(x.positionMm, y.positionMm) <= near) same.unite(int(i), int(j));
        }
    for (std::size_t i = 0; i < cuts.size(); ++i) {
        if (same.find(int(i)) != int(i)) continue;
        ContactInfo merged = cuts[i].info;
        merged.links = 0;
        merged.voxelsRemoved = 0;
        for (std::size_t j = i; j < cuts.size(); ++j) {
            if (same.find(int(j)) != int(i)) continue;
            const ContactInfo& c = cuts[j].info;
            merged.links += 1;
            merged.voxelsRemoved += c.voxelsRemoved;
            if (c.widthMm < merged.widthMm) {
                const std::size_t links = merged.links, removedVoxels = merged.voxelsRemoved;
                merged = c;
                merged.links = links;
                merged.voxelsRemoved = removedVoxels;
            }
        }
        report.contacts.push_back(merged);
    }
    // Reported: cut contacts first, then those kept; each group narrowest first.
    std::stable_sort(report.contacts.begin(), report.contacts.end(),
                     [](const ContactInfo& x, const ContactInfo& y) {
        if (x.cut != y.cut) return x.cut;
        return x.widthMm < y.widthMm;
    });
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
    if (index.slotCount() == 0) return report;

    // 1.-3. Cores, chunks, regions (contact_regions.h).
    RegionGraph g(index, xf, voxelMm, contact_regions::lumenRegions(index, voxelMm, params.chunkMm, progress));
    report.regions = static_cast<std::size_t>(g.flooded.count);
    findPeaks(g);
    reportProgress(progress, 0.5, "contacts: region graph");
    linkRegions(g);
    report.links = g.links.size();
    report.pieces = spanningForest(g.links, g.flooded.count);
    g.nodeMm.resize(g.flooded.count);
    for (std::int32_t r = 0; r < g.flooded.count; ++r) g.nodeMm[r] = g.worldOf(g.peakSlot[r]);
    countWideCycles(g, params, report);
    reportProgress(progress, 0.6, "contacts: narrow links");

    const NarrowLinks narrow = narrowInterfaces(g, params);
    std::vector<std::uint8_t> removed(index.slotCount(), 0);
    std::vector<Cut> cuts;
    cutCycleLinks(g, narrow, params, removed, cuts, progress);
    reportProgress(progress, 0.7, "contacts: tree links");
    cutTreeLinks(g, narrow, params, removed, cuts);
    reportProgress(progress, 0.8, "contacts: cut");
    if (!cuts.empty()) {
        keepCutsThatDoNotSplit(g, narrow, report.pieces, cuts, removed, progress);
        writeCuts(g, narrow, removed, cuts, sdf, mask);
        reportContacts(cuts, voxelMm, report);
    }
    reportProgress(progress, 1.0, "contacts done");
    return report;
}

} // namespace flyover
