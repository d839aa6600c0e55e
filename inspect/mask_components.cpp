// The face-connected components of a mask (mask_components.h).
#include "inspect/mask_components.h"

#include "volume/error.h"
#include "volume/union_find.h"

#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <sstream>
#include <vector>

namespace flyover {

using openvdb::BoolTree;
using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::Index64;

namespace {

std::string num(double v)
{
    std::ostringstream o;
    o.precision(6);
    o << v;
    return o.str();
}

} // namespace

MaskComponents faceConnectedComponents(const BoolTree& mask, const CoordBBox& box)
{
    using Leaf = BoolTree::LeafNodeType;
    constexpr int D = static_cast<int>(Leaf::DIM);
    constexpr int N = static_cast<int>(Leaf::SIZE);
    constexpr uint16_t NONE = 0xFFFF;
    static_assert(D == 8 && N == 512, "offsets below assume 8^3 leaves (offset = x*64 + y*8 + z)");

    // Units: the components within each leaf, then the active tiles (each connected whole).
    std::vector<const Leaf*> leaves;
    mask.getNodes(leaves);
    std::sort(leaves.begin(), leaves.end(), [](const Leaf* a, const Leaf* b) { return a->origin() < b->origin(); });
    std::vector<Coord> leafOrigins(leaves.size());
    for (std::size_t i = 0; i < leaves.size(); ++i) leafOrigins[i] = leaves[i]->origin();
    std::vector<CoordBBox> tiles;
    {
        auto it = mask.cbeginValueOn();
        it.setMaxDepth(BoolTree::ValueOnCIter::LEAF_DEPTH - 1);
        for (; it; ++it) {
            CoordBBox tb;
            it.getBoundingBox(tb);
            tiles.push_back(tb);
        }
        std::sort(tiles.begin(), tiles.end(), [](const CoordBBox& a, const CoordBBox& b) { return a.min() < b.min(); });
    }
    auto onBorder = [&box](const CoordBBox& b) {
        for (int a = 0; a < 3; ++a)
            if (b.min()[a] <= box.min()[a] || b.max()[a] >= box.max()[a]) return true;
        return false;
    };

    struct LeafUnits {
        uint32_t base = 0;
        uint16_t count = 0;
        std::unique_ptr<uint16_t[]> local;  // per offset: local unit, NONE if inactive (only when count > 1)
        std::vector<uint8_t> touches;       // per local unit
    };
    std::vector<LeafUnits> units(leaves.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const tbb::blocked_range<std::size_t>& r) {
        std::array<uint16_t, N> parent;
        std::array<uint16_t, N> label;
        for (std::size_t n = r.begin(); n < r.end(); ++n) {
            const Leaf& leaf = *leaves[n];
            const auto& on = leaf.getValueMask();
            auto find = [&parent](uint16_t i) {
                while (parent[i] != i) { parent[i] = parent[parent[i]]; i = parent[i]; }
                return i;
            };
            auto unite = [&](uint16_t a, uint16_t b) {
                a = find(a); b = find(b);
                if (a < b) parent[b] = a; else if (b < a) parent[a] = b;
            };
            for (int off = 0; off < N; ++off) {
                parent[off] = static_cast<uint16_t>(off);
                if (!on.isOn(off)) continue;
                if ((off & 7) && on.isOn(off - 1)) unite(off, off - 1);
                if ((off & 56) && on.isOn(off - 8)) unite(off, off - 8);
                if ((off & 448) && on.isOn(off - 64)) unite(off, off - 64);
            }
            LeafUnits& u = units[n];
            uint16_t count = 0;
            label.fill(NONE);
            for (int off = 0; off < N; ++off) {
                if (!on.isOn(off)) continue;
                const uint16_t root = find(static_cast<uint16_t>(off));
                if (label[root] == NONE) {
                    label[root] = count++;
                    u.touches.push_back(0);
                }
                const uint16_t l = label[root];
                label[off] = l;
                const Coord c = leaf.offsetToGlobalCoord(static_cast<openvdb::Index>(off));
                if (onBorder(CoordBBox(c, c))) u.touches[l] = 1;
            }
            u.count = count;
            if (count > 1) {
                u.local.reset(new uint16_t[N]);
                for (int off = 0; off < N; ++off) u.local[off] = on.isOn(off) ? label[off] : NONE;
            }
        }
    });
    uint32_t nUnits = 0;
    for (LeafUnits& u : units) {
        u.base = nUnits;
        nUnits += u.count;
    }
    const uint32_t tileBase = nUnits;
    nUnits += static_cast<uint32_t>(tiles.size());
    auto unitOf = [&units, &leaves](std::size_t leaf, int off) -> uint32_t {
        const LeafUnits& u = units[leaf];
        if (u.count == 0 || !leaves[leaf]->isValueOn(static_cast<openvdb::Index>(off)))
            return std::numeric_limits<uint32_t>::max();
        if (u.count == 1) return u.base;
        const uint16_t l = u.local[off];
        return l == NONE ? std::numeric_limits<uint32_t>::max() : u.base + l;
    };
    auto leafIndex = [&leafOrigins](const Coord& origin) -> std::ptrdiff_t {
        auto it = std::lower_bound(leafOrigins.begin(), leafOrigins.end(), origin);
        return it != leafOrigins.end() && *it == origin ? it - leafOrigins.begin() : -1;
    };
    // the active tile holding c (c in no leaf), by its depth's origin
    static const std::array<int, 3> tileDim = {static_cast<int>(BoolTree::RootNodeType::ChildNodeType::DIM),
                                              static_cast<int>(BoolTree::RootNodeType::ChildNodeType::ChildNodeType::DIM),
                                              D};
    auto tileIndex = [&tiles](const openvdb::tree::ValueAccessor<const BoolTree>& acc, const Coord& c) -> std::ptrdiff_t {
        if (!acc.isValueOn(c)) return -1;
        const int depth = acc.getValueDepth(c);
        if (depth < 0 || depth > 2) return -1;
        const int dim = tileDim[static_cast<std::size_t>(depth)];
        const Coord origin(c.x() & ~(dim - 1), c.y() & ~(dim - 1), c.z() & ~(dim - 1));
        auto it = std::lower_bound(tiles.begin(), tiles.end(), origin,
                                   [](const CoordBBox& t, const Coord& o) { return t.min() < o; });
        return it != tiles.end() && it->min() == origin ? it - tiles.begin() : -1;
    };

    // Joins across faces, collected in parallel (each leaf: its + neighbours, and tiles on any
    // side; each tile: tiles on any side), then united in one pass.
    using Edge = std::pair<uint32_t, uint32_t>;
    std::vector<std::vector<Edge>> leafEdges(leaves.size()), tileEdges(tiles.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const BoolTree> acc(mask);
        for (std::size_t n = r.begin(); n < r.end(); ++n) {
            if (units[n].count == 0) continue;
            std::vector<Edge>& edges = leafEdges[n];
            const Leaf& leaf = *leaves[n];
            for (int axis = 0; axis < 3; ++axis)
                for (int side = -1; side <= 1; side += 2) {
                    Coord o = leaf.origin();
                    o[axis] += side * D;
                    const int strideAxis = axis == 0 ? 64 : (axis == 1 ? 8 : 1);
                    const int faceHere = side > 0 ? (D - 1) : 0, faceThere = side > 0 ? 0 : (D - 1);
                    const int a1 = axis == 0 ? 1 : 0, a2 = axis == 2 ? 1 : 2;  // the two other axes
                    const int s1 = a1 == 0 ? 64 : (a1 == 1 ? 8 : 1), s2 = a2 == 0 ? 64 : (a2 == 1 ? 8 : 1);
                    const std::ptrdiff_t other = side > 0 ? leafIndex(o) : -1;
                    if (other >= 0) {
                        for (int i = 0; i < D; ++i)
                            for (int j = 0; j < D; ++j) {
                                const int here = faceHere * strideAxis + i * s1 + j * s2;
                                const int there = faceThere * strideAxis + i * s1 + j * s2;
                                const uint32_t ua = unitOf(n, here), ub = unitOf(static_cast<std::size_t>(other), there);
                                if (ua != std::numeric_limits<uint32_t>::max() && ub != std::numeric_limits<uint32_t>::max())
                                    edges.emplace_back(ua, ub);
                            }
                    } else if (side < 0 && leafIndex(o) >= 0) {
                        continue;  // that leaf joins this one through its + side
                    } else {
                        const std::ptrdiff_t t = tileIndex(acc, o);
                        if (t < 0) continue;
                        for (int i = 0; i < D; ++i)
                            for (int j = 0; j < D; ++j) {
                                const uint32_t ua = unitOf(n, faceHere * strideAxis + i * s1 + j * s2);
                                if (ua != std::numeric_limits<uint32_t>::max())
                                    edges.emplace_back(ua, tileBase + static_cast<uint32_t>(t));
                            }
                    }
                }
            std::sort(edges.begin(), edges.end());
            edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
            edges.shrink_to_fit();
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tiles.size()), [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const BoolTree> acc(mask);
        for (std::size_t n = r.begin(); n < r.end(); ++n) {
            const CoordBBox& tb = tiles[n];
            std::vector<Edge>& edges = tileEdges[n];
            for (int axis = 0; axis < 3; ++axis)
                for (int side = -1; side <= 1; side += 2) {
                    const int a1 = axis == 0 ? 1 : 0, a2 = axis == 2 ? 1 : 2;
                    for (int i = tb.min()[a1]; i <= tb.max()[a1]; i += D)
                        for (int j = tb.min()[a2]; j <= tb.max()[a2]; j += D) {
                            Coord c;
                            c[axis] = side > 0 ? tb.max()[axis] + 1 : tb.min()[axis] - 1;
                            c[a1] = i;
                            c[a2] = j;
                            if (acc.probeConstLeaf(c)) continue;  // the leaf joins this tile
                            const std::ptrdiff_t t = tileIndex(acc, c);
                            if (t >= 0 && static_cast<std::size_t>(t) != n)
                                edges.emplace_back(tileBase + static_cast<uint32_t>(n), tileBase + static_cast<uint32_t>(t));
                        }
                }
            std::sort(edges.begin(), edges.end());
            edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
        }
    });
    UnionFind<uint32_t> joined(nUnits);  // the root is the smallest unit
    auto find = [&joined](uint32_t i) { return joined.find(i); };
    auto unite = [&joined](const Edge& e) { joined.unite(e.first, e.second); };
    for (auto& edges : leafEdges) { for (const Edge& e : edges) unite(e); std::vector<Edge>().swap(edges); }
    for (auto& edges : tileEdges) { for (const Edge& e : edges) unite(e); std::vector<Edge>().swap(edges); }
    std::vector<uint8_t> touches(nUnits, 0);
    for (std::size_t n = 0; n < leaves.size(); ++n)
        for (uint16_t l = 0; l < units[n].count; ++l)
            if (units[n].touches[l]) touches[find(units[n].base + l)] = 1;
    for (std::size_t t = 0; t < tiles.size(); ++t)
        if (onBorder(tiles[t])) touches[find(tileBase + static_cast<uint32_t>(t))] = 1;
    // enclosed components, numbered by their root (the smallest unit: deterministic)
    std::vector<int32_t> componentOf(nUnits, -1);
    MaskComponents out;
    for (uint32_t i = 0; i < nUnits; ++i) {
        const uint32_t root = find(i);
        if (touches[root]) continue;
        if (componentOf[root] < 0) {
            componentOf[root] = static_cast<int32_t>(out.enclosed.size());
            out.enclosed.emplace_back(new BoolTree(false));
        }
        componentOf[i] = componentOf[root];
    }
    out.touching.reset(new BoolTree(mask, false, openvdb::TopologyCopy()));
    if (!out.enclosed.empty()) {
        openvdb::tree::ValueAccessor<BoolTree> outAcc(*out.touching);
        for (std::size_t n = 0; n < leaves.size(); ++n) {
            const LeafUnits& u = units[n];
            bool any = false;
            for (uint16_t l = 0; l < u.count && !any; ++l) any = componentOf[u.base + l] >= 0;
            if (!any) continue;
            for (auto it = leaves[n]->cbeginValueOn(); it; ++it) {
                const int32_t k = componentOf[unitOf(n, static_cast<int>(it.pos()))];
                if (k < 0) continue;
                out.enclosed[static_cast<std::size_t>(k)]->setActiveState(it.getCoord(), true);
                outAcc.setValueOff(it.getCoord());
            }
        }
        for (std::size_t t = 0; t < tiles.size(); ++t) {
            const int32_t k = componentOf[tileBase + static_cast<uint32_t>(t)];
            if (k < 0) continue;
            out.enclosed[static_cast<std::size_t>(k)]->fill(tiles[t], false, true);
            out.touching->fill(tiles[t], false, false);
        }
        openvdb::tools::pruneInactive(*out.touching);
        for (auto& comp : out.enclosed)
            if (comp->hasActiveTiles()) comp->voxelizeActiveTiles();  // voxel iterators visit every voxel
    }
    return out;
}

} // namespace flyover
