// The face-connected components of a mask (mask_components.h).
#include "volume/mask_components.h"

#include "volume/error.h"
#include "volume/union_find.h"

#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <limits>
#include <vector>

namespace flyover {

using openvdb::BoolTree;
using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::Index64;

namespace {

using Leaf = BoolTree::LeafNodeType;
constexpr int D = static_cast<int>(Leaf::DIM);
constexpr int N = static_cast<int>(Leaf::SIZE);
constexpr uint16_t NONE = 0xFFFF;
static_assert(D == 8 && N == 512, "offsets below assume 8^3 leaves (offset = x*64 + y*8 + z)");
/// Voxels along an edge of a tile at depth 0, 1, 2 (a root child, an internal node, a leaf).
const std::array<int, 3> TILE_DIM = {static_cast<int>(BoolTree::RootNodeType::ChildNodeType::DIM),
                                     static_cast<int>(BoolTree::RootNodeType::ChildNodeType::ChildNodeType::DIM), D};
using Edge = std::pair<uint32_t, uint32_t>;  // two units joined across a face

/// Whether b reaches a face of box.
bool onBorder(const CoordBBox& b, const CoordBBox& box)
{
    for (int a = 0; a < 3; ++a)
        if (b.min()[a] <= box.min()[a] || b.max()[a] >= box.max()[a]) return true;
    return false;
}

/// The components within one leaf: units base .. base + count - 1.
struct LeafUnits {
    uint32_t base = 0;
    uint16_t count = 0;
    std::unique_ptr<uint16_t[]> local;  // per offset: local unit, NONE if inactive (only when count > 1)
    std::vector<uint8_t> touches;       // per local unit: touches a face of the box
    std::vector<uint32_t> voxels;       // per local unit: its voxel count
};

/// The units of a mask: the components within each leaf, then the active tiles (each connected
/// whole), numbered leaf by leaf (by origin), then tile by tile (by min corner).
struct MaskUnits {
    std::vector<const Leaf*> leaves;  // by origin
    std::vector<Coord> leafOrigins;
    std::vector<CoordBBox> tiles;     // by min corner
    std::vector<LeafUnits> units;     // per leaf
    uint32_t tileBase = 0, nUnits = 0;

    /// The unit of voxel `off` of leaf `leaf`, uint32 max if inactive.
    uint32_t unitOf(std::size_t leaf, int off) const
    {
        const LeafUnits& u = units[leaf];
        if (u.count == 0 || !leaves[leaf]->isValueOn(static_cast<openvdb::Index>(off)))
            return std::numeric_limits<uint32_t>::max();
        if (u.count == 1) return u.base;
        const uint16_t l = u.local[off];
        return l == NONE ? std::numeric_limits<uint32_t>::max() : u.base + l;
    }
    /// The index of the leaf at `origin`, -1 if none.
    std::ptrdiff_t leafIndex(const Coord& origin) const
    {
        auto it = std::lower_bound(leafOrigins.begin(), leafOrigins.end(), origin);
        return it != leafOrigins.end() && *it == origin ? it - leafOrigins.begin() : -1;
    }
    /// The active tile holding c (c in no leaf), by its depth's origin; -1 if none.
    std::ptrdiff_t tileIndex(const openvdb::tree::ValueAccessor<const BoolTree>& acc, const Coord& c) const
    {
        if (!acc.isValueOn(c)) return -1;
        const int depth = acc.getValueDepth(c);
        if (depth < 0 || depth > 2) return -1;
        const int dim = TILE_DIM[static_cast<std::size_t>(depth)];
        const Coord origin(c.x() & ~(dim - 1), c.y() & ~(dim - 1), c.z() & ~(dim - 1));
        auto it = std::lower_bound(tiles.begin(), tiles.end(), origin,
                                   [](const CoordBBox& t, const Coord& o) { return t.min() < o; });
        return it != tiles.end() && it->min() == origin ? it - tiles.begin() : -1;
    }
};

/// The mask's leaves sorted by origin and its active tiles sorted by min corner.
void collectNodes(const BoolTree& mask, MaskUnits& m)
{
    mask.getNodes(m.leaves);
    std::sort(m.leaves.begin(), m.leaves.end(), [](const Leaf* a, const Leaf* b) { return a->origin() < b->origin(); });
    m.leafOrigins.resize(m.leaves.size());
    for (std::size_t i = 0; i < m.leaves.size(); ++i) m.leafOrigins[i] = m.leaves[i]->origin();
    auto it = mask.cbeginValueOn();
    it.setMaxDepth(BoolTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; it; ++it) {
        CoordBBox tb;
        it.getBoundingBox(tb);
        m.tiles.push_back(tb);
    }
    std::sort(m.tiles.begin(), m.tiles.end(), [](const CoordBBox& a, const CoordBBox& b) { return a.min() < b.min(); });
}

/// The face-connected components within one leaf (a union-find over its offsets), numbered in
/// the order of their first voxel, their voxel counts, and which of them touch a face of box.
void findLeafUnits(const Leaf& leaf, const CoordBBox& box, LeafUnits& u)
{
    std::array<uint16_t, N> parent;
    std::array<uint16_t, N> label;
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
    uint16_t count = 0;
    label.fill(NONE);
    for (int off = 0; off < N; ++off) {
        if (!on.isOn(off)) continue;
        const uint16_t root = find(static_cast<uint16_t>(off));
        if (label[root] == NONE) {
            label[root] = count++;
            u.touches.push_back(0);
            u.voxels.push_back(0);
        }
        const uint16_t l = label[root];
        label[off] = l;
        ++u.voxels[l];
        const Coord c = leaf.offsetToGlobalCoord(static_cast<openvdb::Index>(off));
        if (onBorder(CoordBBox(c, c), box)) u.touches[l] = 1;
    }
    u.count = count;
    if (count > 1) {
        u.local.reset(new uint16_t[N]);
        for (int off = 0; off < N; ++off) u.local[off] = on.isOn(off) ? label[off] : NONE;
    }
}

/// Units: the components within each leaf (in parallel), then the active tiles.
MaskUnits findUnits(const BoolTree& mask, const CoordBBox& box)
{
    MaskUnits m;
    collectNodes(mask, m);
    m.units.resize(m.leaves.size());
    using Range = tbb::blocked_range<std::size_t>;
    tbb::parallel_for(Range(0, m.leaves.size()), [&](const Range& r) {
        for (std::size_t n = r.begin(); n < r.end(); ++n) findLeafUnits(*m.leaves[n], box, m.units[n]);
    });
    uint32_t nUnits = 0;
    for (LeafUnits& u : m.units) {
        u.base = nUnits;
        nUnits += u.count;
    }
    m.tileBase = nUnits;
    nUnits += static_cast<uint32_t>(m.tiles.size());
    m.nUnits = nUnits;
    return m;
}

/// The joins of leaf n's units across its faces: to the leaf on each + side, and to an active
/// tile on any side; sorted, without duplicates.
std::vector<Edge> leafJoins(const MaskUnits& m, const openvdb::tree::ValueAccessor<const BoolTree>& acc, std::size_t n)
{
    std::vector<Edge> edges;
    const Leaf& leaf = *m.leaves[n];
    for (int axis = 0; axis < 3; ++axis)
        for (int side = -1; side <= 1; side += 2) {
            Coord o = leaf.origin();
            o[axis] += side * D;
            const int strideAxis = axis == 0 ? 64 : (axis == 1 ? 8 : 1);
            const int faceHere = side > 0 ? (D - 1) : 0, faceThere = side > 0 ? 0 : (D - 1);
            const int a1 = axis == 0 ? 1 : 0, a2 = axis == 2 ? 1 : 2;  // the two other axes
            const int s1 = a1 == 0 ? 64 : (a1 == 1 ? 8 : 1), s2 = a2 == 0 ? 64 : (a2 == 1 ? 8 : 1);
            const std::ptrdiff_t other = side > 0 ? m.leafIndex(o) : -1;
            if (other >= 0) {
                for (int i = 0; i < D; ++i)
                    for (int j = 0; j < D; ++j) {
                        const int here = faceHere * strideAxis + i * s1 + j * s2;
                        const int there = faceThere * strideAxis + i * s1 + j * s2;
                        const uint32_t ua = m.unitOf(n, here), ub = m.unitOf(static_cast<std::size_t>(other), there);
                        if (ua != std::numeric_limits<uint32_t>::max() && ub != std::numeric_limits<uint32_t>::max())
                            edges.emplace_back(ua, ub);
                    }
            } else if (side < 0 && m.leafIndex(o) >= 0) {
                continue;  // that leaf joins this one through its + side
            } else {
                const std::ptrdiff_t t = m.tileIndex(acc, o);
                if (t < 0) continue;
                for (int i = 0; i < D; ++i)
                    for (int j = 0; j < D; ++j) {
                        const uint32_t ua = m.unitOf(n, faceHere * strideAxis + i * s1 + j * s2);
                        if (ua != std::numeric_limits<uint32_t>::max())
                            edges.emplace_back(ua, m.tileBase + static_cast<uint32_t>(t));
                    }
            }
        }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    edges.shrink_to_fit();
    return edges;
}

/// The joins of tile n to the active tiles on any side; sorted, without duplicates.
std::vector<Edge> tileJoins(const MaskUnits& m, const openvdb::tree::ValueAccessor<const BoolTree>& acc, std::size_t n)
{
    std::vector<Edge> edges;
    const CoordBBox& tb = m.tiles[n];
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
                    const std::ptrdiff_t t = m.tileIndex(acc, c);
                    if (t >= 0 && static_cast<std::size_t>(t) != n)
                        edges.emplace_back(m.tileBase + static_cast<uint32_t>(n),
                                           m.tileBase + static_cast<uint32_t>(t));
                }
        }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    return edges;
}

/// Joins across faces, collected in parallel (each leaf: its + neighbours, and tiles on any
/// side; each tile: tiles on any side), then united in one pass.
UnionFind<uint32_t> joinUnits(const BoolTree& mask, const MaskUnits& m)
{
    using Range = tbb::blocked_range<std::size_t>;
    std::vector<std::vector<Edge>> leafEdges(m.leaves.size()), tileEdges(m.tiles.size());
    tbb::parallel_for(Range(0, m.leaves.size()), [&](const Range& r) {
        openvdb::tree::ValueAccessor<const BoolTree> acc(mask);
        for (std::size_t n = r.begin(); n < r.end(); ++n) {
            if (m.units[n].count == 0) continue;
            leafEdges[n] = leafJoins(m, acc, n);
        }
    });
    tbb::parallel_for(Range(0, m.tiles.size()), [&](const Range& r) {
        openvdb::tree::ValueAccessor<const BoolTree> acc(mask);
        for (std::size_t n = r.begin(); n < r.end(); ++n) tileEdges[n] = tileJoins(m, acc, n);
    });
    UnionFind<uint32_t> joined(m.nUnits);  // the root is the smallest unit
    auto unite = [&joined](const Edge& e) { joined.unite(e.first, e.second); };
    for (auto& edges : leafEdges) { for (const Edge& e : edges) unite(e); std::vector<Edge>().swap(edges); }
    for (auto& edges : tileEdges) { for (const Edge& e : edges) unite(e); std::vector<Edge>().swap(edges); }
    return joined;
}

/// Per root unit: whether its component touches a face of box.
std::vector<uint8_t> touchingRoots(const MaskUnits& m, UnionFind<uint32_t>& joined, const CoordBBox& box)
{
    std::vector<uint8_t> touches(m.nUnits, 0);
    for (std::size_t n = 0; n < m.leaves.size(); ++n)
        for (uint16_t l = 0; l < m.units[n].count; ++l)
            if (m.units[n].touches[l]) touches[joined.find(m.units[n].base + l)] = 1;
    for (std::size_t t = 0; t < m.tiles.size(); ++t)
        if (onBorder(m.tiles[t], box)) touches[joined.find(m.tileBase + static_cast<uint32_t>(t))] = 1;
    return touches;
}

/// Per unit: its enclosed component's index, -1 for a touching one; creates the enclosed
/// components' empty masks in out.
std::vector<int32_t> numberEnclosed(const MaskUnits& m, UnionFind<uint32_t>& joined,
                                    const std::vector<uint8_t>& touches, MaskComponents& out)
{
    // enclosed components, numbered by their root (the smallest unit: deterministic)
    std::vector<int32_t> componentOf(m.nUnits, -1);
    for (uint32_t i = 0; i < m.nUnits; ++i) {
        const uint32_t root = joined.find(i);
        if (touches[root]) continue;
        if (componentOf[root] < 0) {
            componentOf[root] = static_cast<int32_t>(out.enclosed.size());
            out.enclosed.emplace_back(new BoolTree(false));
        }
        componentOf[i] = componentOf[root];
    }
    return componentOf;
}

/// Moves the enclosed components' voxels and tiles from out.touching (a copy of the mask) into
/// their own masks.
void assembleEnclosed(const MaskUnits& m, const std::vector<int32_t>& componentOf, MaskComponents& out)
{
    openvdb::tree::ValueAccessor<BoolTree> outAcc(*out.touching);
    for (std::size_t n = 0; n < m.leaves.size(); ++n) {
        const LeafUnits& u = m.units[n];
        bool any = false;
        for (uint16_t l = 0; l < u.count && !any; ++l) any = componentOf[u.base + l] >= 0;
        if (!any) continue;
        for (auto it = m.leaves[n]->cbeginValueOn(); it; ++it) {
            const int32_t k = componentOf[m.unitOf(n, static_cast<int>(it.pos()))];
            if (k < 0) continue;
            out.enclosed[static_cast<std::size_t>(k)]->setActiveState(it.getCoord(), true);
            outAcc.setValueOff(it.getCoord());
        }
    }
    for (std::size_t t = 0; t < m.tiles.size(); ++t) {
        const int32_t k = componentOf[m.tileBase + static_cast<uint32_t>(t)];
        if (k < 0) continue;
        out.enclosed[static_cast<std::size_t>(k)]->fill(m.tiles[t], false, true);
        out.touching->fill(m.tiles[t], false, false);
    }
    openvdb::tools::pruneInactive(*out.touching);
    for (auto& comp : out.enclosed)
        if (comp->hasActiveTiles()) comp->voxelizeActiveTiles();  // voxel iterators visit every voxel
}

/// Per unit: its component's index, components numbered by voxel count (largest first; equal
/// counts by their root, the smallest unit: deterministic); also the count of components.
std::vector<uint32_t> numberBySize(const MaskUnits& m, UnionFind<uint32_t>& joined, std::size_t& nComponents)
{
    std::vector<uint64_t> voxels(m.nUnits, 0);
    for (std::size_t n = 0; n < m.leaves.size(); ++n)
        for (uint16_t l = 0; l < m.units[n].count; ++l) voxels[joined.find(m.units[n].base + l)] += m.units[n].voxels[l];
    for (std::size_t t = 0; t < m.tiles.size(); ++t)
        voxels[joined.find(m.tileBase + static_cast<uint32_t>(t))] += m.tiles[t].volume();
    std::vector<uint32_t> roots;
    for (uint32_t i = 0; i < m.nUnits; ++i)
        if (joined.find(i) == i) roots.push_back(i);
    std::stable_sort(roots.begin(), roots.end(), [&](uint32_t a, uint32_t b) { return voxels[a] > voxels[b]; });
    std::vector<uint32_t> indexOfRoot(m.nUnits, 0), componentOf(m.nUnits);
    for (std::size_t k = 0; k < roots.size(); ++k) indexOfRoot[roots[k]] = static_cast<uint32_t>(k);
    for (uint32_t i = 0; i < m.nUnits; ++i) componentOf[i] = indexOfRoot[joined.find(i)];
    nComponents = roots.size();
    return componentOf;
}

} // namespace

std::vector<BoolTree::Ptr> connectedComponents(const BoolTree& tree)
{
    const CoordBBox everywhere(Coord(std::numeric_limits<int>::min()), Coord(std::numeric_limits<int>::max()));
    const MaskUnits units = findUnits(tree, everywhere);
    UnionFind<uint32_t> joined = joinUnits(tree, units);
    std::size_t nComponents = 0;
    const std::vector<uint32_t> componentOf = numberBySize(units, joined, nComponents);
    std::vector<BoolTree::Ptr> components(nComponents);
    for (auto& c : components) c.reset(new BoolTree(tree.background()));
    // Each component's leaves hold the input's values on its voxels (the background elsewhere);
    // tiles become voxels, so leaf iterators see every voxel.
    std::vector<openvdb::tree::ValueAccessor<BoolTree>> acc;
    acc.reserve(nComponents);
    for (auto& c : components) acc.emplace_back(*c);
    for (std::size_t n = 0; n < units.leaves.size(); ++n) {
        const Leaf& leaf = *units.leaves[n];
        const LeafUnits& u = units.units[n];
        if (u.count == 1) {
            auto* copy = new Leaf(leaf.origin(), tree.background());
            for (auto it = leaf.cbeginValueOn(); it; ++it) copy->setValueOn(it.pos(), *it);
            acc[componentOf[u.base]].addLeaf(copy);
            continue;
        }
        for (auto it = leaf.cbeginValueOn(); it; ++it)
            acc[componentOf[units.unitOf(n, static_cast<int>(it.pos()))]].setValueOn(it.getCoord(), *it);
    }
    openvdb::tree::ValueAccessor<const BoolTree> in(tree);
    for (std::size_t t = 0; t < units.tiles.size(); ++t)
        components[componentOf[units.tileBase + static_cast<uint32_t>(t)]]->fill(
            units.tiles[t], in.getValue(units.tiles[t].min()), true);
    for (auto& c : components)
        if (c->hasActiveTiles()) c->voxelizeActiveTiles();
    return components;
}

MaskComponents faceConnectedComponents(const BoolTree& mask, const CoordBBox& box)
{
    const MaskUnits units = findUnits(mask, box);
    UnionFind<uint32_t> joined = joinUnits(mask, units);
    const std::vector<uint8_t> touches = touchingRoots(units, joined, box);
    MaskComponents out;
    const std::vector<int32_t> componentOf = numberEnclosed(units, joined, touches, out);
    out.touching.reset(new BoolTree(mask, false, openvdb::TopologyCopy()));
    if (!out.enclosed.empty()) assembleEnclosed(units, componentOf, out);
    return out;
}

} // namespace flyover
