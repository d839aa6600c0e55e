// The heavy OpenVDB tool families used by segmentation live in this translation unit only
// (style.md §4). All of them are pre-instantiated for the tree types used here. The fast
// sweeping redistance is in redistance.cpp.
#include "volume/segment_tools.h"

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <unordered_set>
#include <vector>

namespace flyover::detail {

namespace {

using BoolLeaf = openvdb::BoolTree::LeafNodeType;
using openvdb::Coord;
using Word = std::uint64_t;
/// A leaf's active voxels as 8 words: word x holds bit y << 3 | z (NodeMask<3>'s layout).
using LeafBits = std::array<Word, 8>;
constexpr int LEAF_DIM = 8;
static_assert(int(BoolLeaf::DIM) == LEAF_DIM, "box morphology below assumes 8^3 leaves");

/// Leaf origins with their bits, found by origin.
struct LeafSet {
    std::vector<Coord> origins;
    std::vector<LeafBits> bits;
    std::unordered_map<Coord, std::size_t> index;

    const LeafBits* find(const Coord& o) const
    {
        const auto it = index.find(o);
        return it == index.end() ? nullptr : &bits[it->second];
    }
};

/// Per byte lane, the bits kept by a right shift of `rem` within the lane (rem in 0..7).
constexpr Word laneLow(int rem)
{
    return Word(0x0101010101010101ull) * Word(0xffu >> rem);
}

/// One pass of a 1D box dilation (OR) or erosion (AND) of half-width r along `axis` (0: x,
/// 1: y, 2: z): out(p) = OR / AND of in(p + s e_axis) over s in [-r, r], voxels of missing
/// leaves being off. Dilation may create leaves up to ceil(r / 8) leaves away; erosion keeps
/// only the input's leaves. Leaves whose result is empty are left out.
LeafSet boxPass(const LeafSet& in, int axis, int r, bool dilate)
{
    const int K = (r + LEAF_DIM - 1) / LEAF_DIM;  // neighbour leaves read on either side
    std::vector<Coord> candidates;
    if (dilate) {
        std::unordered_set<Coord> seen;
        seen.reserve(in.origins.size() * 2);
        for (const Coord& o : in.origins)
            for (int k = -K; k <= K; ++k) {
                Coord q = o;
                q[axis] += k * LEAF_DIM;
                if (seen.insert(q).second) candidates.push_back(q);
            }
    } else {
        candidates = in.origins;
    }
    std::vector<LeafBits> results(candidates.size());
    std::vector<std::uint8_t> nonEmpty(candidates.size(), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, candidates.size(), 256),
                      [&](const tbb::blocked_range<std::size_t>& range) {
        std::vector<const LeafBits*> line(std::size_t(2 * K + 1));
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            for (int k = -K; k <= K; ++k) {
                Coord q = candidates[c];
                q[axis] += k * LEAF_DIM;
                line[std::size_t(k + K)] = in.find(q);
            }
            // The word of leaf `k` (index into line) at word index x, 0 for a missing leaf.
            auto word = [&](int k, int x) -> Word {
                if (k < 0 || k > 2 * K) return 0;
                const LeafBits* b = line[std::size_t(k)];
                return b ? (*b)[std::size_t(x)] : 0;
            };
            LeafBits out;
            for (int x = 0; x < LEAF_DIM; ++x) {
                Word acc = dilate ? 0 : ~Word(0);
                for (int s = -r; s <= r; ++s) {
                    const int p = K * LEAF_DIM + s;  // position of this leaf's first voxel, shifted by s
                    const int q = p >> 3, rem = p & 7;
                    Word v;
                    if (axis == 0) {
                        const int px = p + x;
                        v = word(px >> 3, px & 7);
                    } else if (axis == 1) {
                        // Bytes (rows of y) of word x along y.
                        v = rem == 0 ? word(q, x) : (word(q, x) >> (8 * rem)) | (word(q + 1, x) << (64 - 8 * rem));
                    } else {
                        // Bits (z) within each byte lane along z.
                        v = rem == 0 ? word(q, x)
                                     : ((word(q, x) >> rem) & laneLow(rem)) |
                                           ((word(q + 1, x) << (8 - rem)) & ~laneLow(rem));
                    }
                    if (dilate) acc |= v;
                    else acc &= v;
                }
                out[std::size_t(x)] = acc;
            }
            bool any = false;
            for (Word w : out) any |= w != 0;
            nonEmpty[c] = any;
            results[c] = out;
        }
    });
    LeafSet next;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
        if (!nonEmpty[c]) continue;
        next.index.emplace(candidates[c], next.origins.size());
        next.origins.push_back(candidates[c]);
        next.bits.push_back(results[c]);
    }
    return next;
}

/// Dilation (erosion) of the active voxels by the cube of half side `iterations` (what as
/// many 26-neighbour steps give), as three 1D passes on the leaves' bit masks; the tree's
/// values are left as they are, new leaves hold the background. The tree has no active tiles.
void boxMorphology(openvdb::BoolTree& tree, int iterations, bool dilate)
{
    LeafSet set;
    {
        std::vector<const BoolLeaf*> leaves;
        tree.getNodes(leaves);
        set.origins.reserve(leaves.size());
        set.bits.resize(leaves.size());
        for (std::size_t n = 0; n < leaves.size(); ++n) {
            set.origins.push_back(leaves[n]->origin());
            const auto& mask = leaves[n]->getValueMask();
            for (int x = 0; x < LEAF_DIM; ++x) set.bits[n][std::size_t(x)] = mask.template getWord<Word>(openvdb::Index(x));
        }
        set.index.reserve(leaves.size() * 2);
        for (std::size_t n = 0; n < leaves.size(); ++n) set.index.emplace(set.origins[n], n);
    }
    // Passes of half-width at most 3 leaves, so that a line of 7 leaves is read at most.
    constexpr int MAX_PASS = 3 * LEAF_DIM;
    for (int axis = 0; axis < 3; ++axis)
        for (int left = iterations; left > 0; left -= MAX_PASS) set = boxPass(set, axis, std::min(left, MAX_PASS), dilate);
    if (dilate) {
        for (std::size_t n = 0; n < set.origins.size(); ++n) {
            BoolLeaf* leaf = tree.touchLeaf(set.origins[n]);
            auto& mask = leaf->getValueMask();
            for (int x = 0; x < LEAF_DIM; ++x) mask.template getWord<Word>(openvdb::Index(x)) = set.bits[n][std::size_t(x)];
        }
    } else {
        std::vector<BoolLeaf*> leaves;
        tree.getNodes(leaves);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t n = r.begin(); n != r.end(); ++n) {
                const LeafBits* b = set.find(leaves[n]->origin());
                auto& mask = leaves[n]->getValueMask();
                for (int x = 0; x < LEAF_DIM; ++x)
                    mask.template getWord<Word>(openvdb::Index(x)) = b ? (*b)[std::size_t(x)] : 0;
            }
        });
    }
}

} // namespace

void dilateVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours)
{
    if (iterations <= 0) return;
    if (neighbours == Neighbours::All && !tree.hasActiveTiles()) {
        boxMorphology(tree, iterations, true);
        return;
    }
    openvdb::tools::dilateActiveValues(tree, iterations,
                                       neighbours == Neighbours::Face
                                           ? openvdb::tools::NN_FACE
                                           : openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::IGNORE_TILES);
}

void erodeVoxels(openvdb::BoolTree& tree, int iterations, Neighbours neighbours)
{
    if (iterations <= 0) return;
    if (neighbours == Neighbours::All && !tree.hasActiveTiles()) {
        boxMorphology(tree, iterations, false);
        openvdb::tools::pruneInactive(tree);
        return;
    }
    openvdb::tools::erodeActiveValues(tree, iterations,
                                      neighbours == Neighbours::Face
                                          ? openvdb::tools::NN_FACE
                                          : openvdb::tools::NN_FACE_EDGE_VERTEX,
                                      openvdb::tools::IGNORE_TILES);
    openvdb::tools::pruneInactive(tree);
}

openvdb::BoolTree::Ptr reachableWithin(const openvdb::BoolTree& seed,
                                       const openvdb::BoolTree& allowed, int maxIterations)
{
    auto reach = std::make_shared<openvdb::BoolTree>(seed);
    openvdb::Index64 count = reach->activeVoxelCount();
    for (int i = 0; i < maxIterations; ++i) {
        dilateVoxels(*reach, 1, Neighbours::Face);
        reach->topologyIntersection(allowed);
        reach->topologyUnion(seed);
        const openvdb::Index64 now = reach->activeVoxelCount();
        if (now == count) break;
        count = now;
    }
    return reach;
}

void trimExteriorBand(openvdb::FloatTree& sdf, float bandMm)
{
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(sdf);
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it)
            if (!(*it <= bandMm)) leaf.setValueOff(it.pos(), bandMm);
    });
    openvdb::tools::changeLevelSetBackground(sdf, bandMm);
    openvdb::tools::pruneLevelSet(sdf);
}

void pruneInactive(openvdb::BoolTree& tree) { openvdb::tools::pruneInactive(tree); }
void pruneInactive(openvdb::FloatTree& tree) { openvdb::tools::pruneInactive(tree); }

} // namespace flyover::detail
