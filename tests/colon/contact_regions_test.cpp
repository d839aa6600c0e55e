// The contact search's regions (colon/contact_regions.h: cores, chunks, priority flood) against
// a plain reference: the implementation it replaced (byte flags, a steps array, the flood reading
// each neighbour's region), kept here as the definition of the result. Random unions of balls
// and thin necks, with depths as computed and quantized to the flood's bins (ties), several
// seeds and chunk lengths: every slot's region must be the same.
#include "colon/contact_regions.h"

#include "colon/lumen_index.h"

#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace flyover {
namespace {

using namespace lumen_index;

/// The former steps 1-3 of cutContacts, unchanged.
contact_regions::Regions referenceRegions(const LumenIndex& index, double voxelMm, double chunkMm)
{
    const std::size_t n = index.slotCount();
    std::vector<std::uint8_t> core(n, 0);
    const std::vector<float> nearby = nearbyMaxDepth(index);
    for (std::size_t s = 0; s < n; ++s) {
        const float d = index.depthMm[s];
        core[s] = d >= static_cast<float>(voxelMm) && d >= 0.5f * nearby[s / LEAF_VOXELS];
    }
    std::vector<std::int32_t> region(n, -1);
    std::int32_t regionCount = 0;
    {
        std::vector<std::int32_t> shell(n, -1), steps(n, -1);
        const double shellSteps = std::max(1.0, chunkMm / (1.2 * voxelMm));
        std::vector<Slot> queue;
        for (Slot s = 0; s < n; ++s) {
            if (!core[s] || steps[s] >= 0) continue;
            queue.assign(1, s);
            steps[s] = 0;
            for (std::size_t head = 0; head < queue.size(); ++head) {
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
    float maxDepth = 0.0f;
    for (std::size_t s = 0; s < n; ++s) maxDepth = std::max(maxDepth, index.depthMm[s]);
    const double binMm = 0.25 * voxelMm;
    const int bins = static_cast<int>(maxDepth / binMm) + 1;
    auto binOf = [&](Slot s) { return std::min(bins - 1, static_cast<int>(double(index.depthMm[s]) / binMm)); };
    std::vector<std::vector<Slot>> buckets(static_cast<std::size_t>(bins));
    for (Slot s = 0; s < n; ++s)
        if (region[s] >= 0) buckets[binOf(s)].push_back(s);
    for (int b = bins - 1; b >= 0; --b) {
        std::vector<Slot>& bucket = buckets[b];
        for (std::size_t i = 0; i < bucket.size(); ++i) {
            const Slot u = bucket[i];
            const std::int32_t r = region[u];
            index.forEachNeighbour(u, [&](Slot t, int) {
                if (region[t] == -1) {
                    region[t] = r;
                    buckets[std::min(b, binOf(t))].push_back(t);
                }
            });
        }
    }
    contact_regions::labelUnreachedPieces(index, region, regionCount);
    return {std::move(region), regionCount};
}

/// A random lumen in a 56^3 box: a chain of balls (a bent tube), balls joined to it by thin
/// necks, and a thin slab apart from it (no core voxel: a region of its own). Negative inside;
/// every voxel within 3 voxels of the surface or inside is active. With `quantize`, depths are
/// multiples of a quarter voxel (many equal depths: ties in the flood).
openvdb::FloatGrid::Ptr randomLumen(unsigned seed, double voxelMm, bool quantize)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    struct Ball {
        double x, y, z, r;
    };
    std::vector<Ball> balls;
    const int size = 56;
    double x = 10, y = 10 + 36 * u(rng), z = 10 + 36 * u(rng);
    for (int i = 0; i < 40; ++i) {
        balls.push_back({x, y, z, 2.5 + 4.0 * u(rng)});
        x = std::clamp(x + 2.0 * u(rng), 8.0, 48.0);
        y = std::clamp(y + 4.0 * (u(rng) - 0.5), 8.0, 48.0);
        z = std::clamp(z + 4.0 * (u(rng) - 0.5), 8.0, 48.0);
    }
    for (int i = 0; i < 4; ++i) {  // side pockets through necks (a chain of small balls)
        const Ball& from = balls[static_cast<std::size_t>(u(rng) * 39)];
        const double dx = u(rng) - 0.5, dy = u(rng) - 0.5, dz = u(rng) - 0.5;
        const double len = std::sqrt(dx * dx + dy * dy + dz * dz) + 1e-9;
        for (int k = 1; k <= 10; ++k) {
            const double t = from.r + 0.8 * k;
            balls.push_back({std::clamp(from.x + t * dx / len, 3.0, 52.0), std::clamp(from.y + t * dy / len, 3.0, 52.0),
                             std::clamp(from.z + t * dz / len, 3.0, 52.0), k == 10 ? 4.0 : 0.9});
        }
    }
    auto grid = openvdb::FloatGrid::create(static_cast<float>(3 * voxelMm));
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelMm));
    auto acc = grid->getAccessor();
    for (int i = 0; i < size; ++i)
        for (int j = 0; j < size; ++j)
            for (int k = 0; k < size; ++k) {
                double d = 1e9;
                for (const Ball& b : balls)
                    d = std::min(d, std::sqrt((i - b.x) * (i - b.x) + (j - b.y) * (j - b.y) +
                                              (k - b.z) * (k - b.z)) - b.r);
                if (i >= 2 && i <= 40 && j >= 50 && j <= 51 && k >= 2 && k <= 30)
                    d = std::min(d, -0.3);  // the slab: two voxels thick, shallower than a voxel
                if (quantize) d = std::round(d * 4.0) / 4.0;
                d *= voxelMm;
                if (d < 3 * voxelMm) acc.setValue(openvdb::Coord(i, j, k), static_cast<float>(d));
            }
    return grid;
}

/// The flood's ways of sharing its work: one entry at a time (one thread), and the two-pass
/// batches (contact_regions.h) in arenas of 2 and 4 threads, every batch or the large ones.
struct FloodRun {
    int threads;
    contact_regions::FloodOptions options;
    const char* what;
};
const std::vector<FloodRun>& floodRuns()
{
    static const std::vector<FloodRun> runs = {
        {1, {}, "1 thread"},
        {2, {1, 3}, "2 threads, every batch in two passes, 3 entries a task"},
        {4, {1, 1}, "4 threads, every batch in two passes, 1 entry a task"},
        {2, {64, 16}, "2 threads, batches of 64 or more in two passes, 16 entries a task"},
        {4, {}, "4 threads, default batches"},
    };
    return runs;
}

contact_regions::Regions regionsIn(const FloodRun& run, const LumenIndex& index, double voxelMm, double chunkMm)
{
    tbb::task_arena arena(run.threads);
    contact_regions::Regions regions;
    arena.execute([&] { regions = contact_regions::lumenRegions(index, voxelMm, chunkMm, nullptr, run.options); });
    return regions;
}

TEST(ContactRegions, SameAsTheReferenceFloodOnRandomLumens)
{
    openvdb::initialize();
    int compared = 0;
    for (unsigned seed = 1; seed <= 6; ++seed)
        for (bool quantize : {false, true})
            for (double chunkMm : {3.0, 10.0}) {
                const double voxelMm = seed % 2 ? 1.0 : 0.7;
                const auto grid = randomLumen(seed, voxelMm, quantize);
                const LumenIndex index = buildIndex(grid->tree());
                ASSERT_GT(index.slotCount(), 0u);
                const contact_regions::Regions expected = referenceRegions(index, voxelMm, chunkMm);
                for (const FloodRun& run : floodRuns()) {
                    const contact_regions::Regions seen = regionsIn(run, index, voxelMm, chunkMm);
                    std::ostringstream what;
                    what << "seed " << seed << ", voxel " << voxelMm << " mm, chunk " << chunkMm << " mm"
                         << (quantize ? ", quantized depths" : "") << ", " << run.what;
                    ASSERT_GT(expected.count, 3) << what.str() << ": expected several regions";
                    EXPECT_EQ(seen.count, expected.count) << what.str() << ": region count";
                    ASSERT_EQ(seen.region.size(), expected.region.size()) << what.str();
                    std::size_t differ = 0, first = 0;
                    for (std::size_t s = 0; s < expected.region.size(); ++s)
                        if (seen.region[s] != expected.region[s] && differ++ == 0) first = s;
                    EXPECT_EQ(differ, 0u) << what.str() << ": " << differ << " slots differ; first at slot " << first
                                          << " " << index.coord(static_cast<Slot>(first)) << ": expected region "
                                          << expected.region[first] << ", seen " << seen.region[first];
                    ++compared;
                }
            }
    EXPECT_EQ(compared, 24 * 5);
}

/// A lumen large enough for the default batches: tubes of radius 6-9 voxels winding through a
/// 96^3 box, touching in places.
TEST(ContactRegions, ParallelFloodSameAsOneByOneOnALargeLumen)
{
    openvdb::initialize();
    const double voxelMm = 0.7;
    auto grid = openvdb::FloatGrid::create(static_cast<float>(3 * voxelMm));
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelMm));
    auto acc = grid->getAccessor();
    const int size = 96;
    for (int i = 0; i < size; ++i)
        for (int j = 0; j < size; ++j)
            for (int k = 0; k < size; ++k) {
                // Two sine-bent tubes along x and one along z: they cross and touch.
                const double a = std::hypot(j - 30 - 10 * std::sin(i * 0.15), k - 30 - 8 * std::cos(i * 0.1)) - 8.0;
                const double b = std::hypot(j - 62 - 6 * std::sin(i * 0.2), k - 60) - 9.0;
                const double c = std::hypot(i - 48 - 12 * std::sin(k * 0.12), j - 46) - 6.0 - 2 * std::sin(k * 0.3);
                const double d = std::min({a, b, c}) * voxelMm;
                if (d < 3 * voxelMm) acc.setValue(openvdb::Coord(i, j, k), static_cast<float>(d));
            }
    const LumenIndex index = buildIndex(grid->tree());
    const contact_regions::Regions expected = regionsIn(floodRuns()[0], index, voxelMm, 6.0);
    ASSERT_GT(expected.count, 10) << "expected many regions";
    for (const FloodRun& run : floodRuns()) {
        const contact_regions::Regions seen = regionsIn(run, index, voxelMm, 6.0);
        EXPECT_EQ(seen.count, expected.count) << run.what << ": region count";
        std::size_t differ = 0;
        for (std::size_t s = 0; s < expected.region.size(); ++s) differ += seen.region[s] != expected.region[s];
        EXPECT_EQ(differ, 0u) << run.what << ": slots whose region differs from the one-thread flood's";
    }
}

/// The 26-connected pieces of the lumen voxels not removed: a search of the whole lumen.
std::size_t referencePieces(const LumenIndex& index, const std::vector<std::uint8_t>& removed)
{
    std::vector<std::uint8_t> seen(index.slotCount(), 0);
    std::vector<Slot> queue;
    std::size_t count = 0;
    for (Slot s = 0; s < index.slotCount(); ++s) {
        if (!index.isLumen(s) || removed[s] || seen[s]) continue;
        ++count;
        queue.assign(1, s);
        seen[s] = 1;
        for (std::size_t head = 0; head < queue.size(); ++head)
            index.forEachNeighbour(queue[head], [&](Slot t, int) {
                if (!seen[t] && !removed[t]) {
                    seen[t] = 1;
                    queue.push_back(t);
                }
            });
    }
    return count;
}

TEST(ContactRegions, PiecesWithoutRemovedVoxelsSameAsASearchOfTheWholeLumen)
{
    openvdb::initialize();
    int split = 0, compared = 0;
    for (unsigned seed = 1; seed <= 4; ++seed) {
        const double voxelMm = 1.0;
        const auto grid = randomLumen(seed, voxelMm, seed % 2 == 0);
        const LumenIndex index = buildIndex(grid->tree());
        const contact_regions::Regions regions = contact_regions::lumenRegions(index, voxelMm, 6.0);
        std::vector<std::pair<std::int32_t, std::int32_t>> touching;
        for (Slot s = 0; s < index.slotCount(); ++s)
            if (index.isLumen(s))
                index.forEachNeighbour(s, [&](Slot t, int) {
                    if (regions.region[t] != regions.region[s])
                        touching.push_back({regions.region[s], regions.region[t]});
                });
        std::vector<Slot> lumen;
        for (Slot s = 0; s < index.slotCount(); ++s)
            if (index.isLumen(s)) lumen.push_back(s);
        std::mt19937 rng(seed);
        for (int trial = 0; trial < 12; ++trial) {
            // Remove balls of voxels (radius 0-5) around random lumen voxels, or whole planes
            // across the lumen (they split it), as cuts do.
            std::vector<std::uint8_t> removed(index.slotCount(), 0);
            std::vector<Slot> removedSlots;
            const int balls = 1 + trial % 4;
            for (int b = 0; b < balls; ++b) {
                const openvdb::Coord c = index.coord(lumen[rng() % lumen.size()]);
                const int r = static_cast<int>(rng() % 6);
                for (Slot s : lumen) {
                    const openvdb::Coord d = index.coord(s) - c;
                    const bool inBall = d.x() * d.x() + d.y() * d.y() + d.z() * d.z() <= r * r;
                    const bool inPlane = trial >= 8 && d.x() >= 0 && d.x() <= 1;
                    if ((inBall || inPlane) && !removed[s]) {
                        removed[s] = 1;
                        removedSlots.push_back(s);
                    }
                }
            }
            const std::size_t expected = referencePieces(index, removed);
            const std::size_t seen = contact_regions::piecesWithout(index, regions, touching, removed, removedSlots);
            EXPECT_EQ(seen, expected) << "seed " << seed << ", trial " << trial << ", " << removedSlots.size()
                                      << " voxels removed: pieces expected " << expected << ", seen " << seen;
            split += expected > 2;  // the slab is a piece of its own
            ++compared;
        }
    }
    EXPECT_EQ(compared, 48);
    EXPECT_GT(split, 3) << "expected some removals to split the lumen";
}

} // namespace
} // namespace flyover
