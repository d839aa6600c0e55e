#include "colon/lumen_index.h"

#include "volume/error.h"

#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace flyover::lumen_index {

namespace {

std::array<Step, 26> makeSteps()
{
    std::array<Step, 26> steps{};
    int n = 0;
    for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz) {
                if (dx == 0 && dy == 0 && dz == 0) continue;
                steps[n++] = {dx, dy, dz, std::sqrt(double(dx * dx + dy * dy + dz * dz))};
            }
    return steps;
}

} // namespace

const std::array<Step, 26> STEPS = makeSteps();

LumenIndex buildIndex(const FloatTree& sdf)
{
    openvdb::tree::LeafManager<const FloatTree> leaves(sdf);
    std::vector<char> hasLumen(leaves.leafCount(), 0);
    leaves.foreach([&](const FloatLeaf& leaf, std::size_t n) {
        for (auto it = leaf.cbeginValueOn(); it; ++it)
            if (*it < 0.0f) {
                hasLumen[n] = 1;
                return;
            }
    });
    LumenIndex index;
    std::vector<const FloatLeaf*> blockLeaf;
    for (std::size_t n = 0; n < leaves.leafCount(); ++n)
        if (hasLumen[n]) {
            blockLeaf.push_back(&leaves.leaf(n));
            index.blockOrigin.push_back(leaves.leaf(n).origin());
        }
    const std::size_t blocks = blockLeaf.size();
    if (blocks >= (std::size_t(NO_SLOT) / LEAF_VOXELS)) {
        std::ostringstream msg;
        msg << "the lumen spans " << blocks
            << " leaf nodes, more than the 32-bit voxel index supports";
        throw InputError(msg.str());
    }
    openvdb::Int32Tree blockId(-1);
    for (std::size_t b = 0; b < blocks; ++b)
        blockId.setValueOn(index.blockOrigin[b], static_cast<std::int32_t>(b));

    index.neighbour.resize(blocks);
    index.depthMm.assign(blocks * LEAF_VOXELS, -1.0f);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const openvdb::Int32Tree> acc(blockId);
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            int k = 0;
            for (int dx = -1; dx <= 1; ++dx)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dz = -1; dz <= 1; ++dz) {
                        std::int32_t id = -1;
                        const Coord o = index.blockOrigin[b] + Coord(dx * LEAF_DIM, dy * LEAF_DIM, dz * LEAF_DIM);
                        if (!acc.probeValue(o, id)) id = -1;
                        index.neighbour[b][k++] = id;
                    }
            float* depth = &index.depthMm[b * LEAF_VOXELS];
            for (auto it = blockLeaf[b]->cbeginValueOn(); it; ++it)
                if (*it < 0.0f) depth[it.pos()] = -*it;
        }
    });
    return index;
}

std::vector<float> nearbyMaxDepth(const LumenIndex& index)
{
    const std::size_t blocks = index.blockOrigin.size();
    std::vector<float> own(blocks, 0.0f), nearby(blocks, 0.0f);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            const float* d = &index.depthMm[b * LEAF_VOXELS];
            own[b] = *std::max_element(d, d + LEAF_VOXELS);
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            float m = 0.0f;
            for (std::int32_t nb : index.neighbour[b])
                if (nb >= 0) m = std::max(m, own[static_cast<std::size_t>(nb)]);
            nearby[b] = m;
        }
    });
    return nearby;
}
} // namespace flyover::lumen_index
