// The route search from both ends (colon/route_search.h) against the search from one end:
// the same minimal cost on lumens with many routes (a block with random walls, a long tube of
// random weights), a route that is a chain of allowed 26-neighbours from the source to the
// target whose summed cost is that minimum, the same route whatever the thread count, and
// the edge cases (no route, source = target, the heap for a wide weight range).
#include "colon/route_search.h"

#include "volume/error.h"

#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <queue>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace flyover {
namespace {

using namespace lumen_index;
using route_search::RouteWorkspace;

/// allowed = 1 at the lumen's slots, 0 at the holes (route_search.h's precondition).
std::vector<std::uint8_t> lumenSlots(const LumenIndex& index)
{
    std::vector<std::uint8_t> allowed(index.slotCount(), 0);
    for (Slot s = 0; s < index.slotCount(); ++s) allowed[s] = index.isLumen(s);
    return allowed;
}

/// A lumen of the voxels (i, j, k) in [0, nx) x [0, ny) x [0, nz) for which keep(i, j, k).
template<typename Keep>
LumenIndex boxLumen(int nx, int ny, int nz, Keep&& keep)
{
    auto grid = openvdb::FloatGrid::create(3.0f);
    auto acc = grid->getAccessor();
    for (int i = 0; i < nx; ++i)
        for (int j = 0; j < ny; ++j)
            for (int k = 0; k < nz; ++k)
                if (keep(i, j, k)) acc.setValue(openvdb::Coord(i, j, k), -1.0f);
    return buildIndex(grid->tree());
}

Slot slotAt(const LumenIndex& index, const openvdb::Coord& c)
{
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (index.isLumen(s) && index.coord(s) == c) return s;
    return NO_SLOT;
}

/// Edge costs as the centerline's: step length times the mean of the two ends' weights; with
/// `noDiagonalAbove`, +infinity (no edge) for a step that is not along an axis between two
/// slots of weights above it (as the coarse search's steps where the inscribed balls miss).
struct Costs {
    std::vector<float> weight;
    double minEdge = 0, maxEdge = 0;
    double noDiagonalAbove = std::numeric_limits<double>::infinity();
    double operator()(Slot u, Slot v, int k) const
    {
        if (STEPS[k].lengthVoxels > 1.0 && weight[u] > noDiagonalAbove && weight[v] > noDiagonalAbove)
            return std::numeric_limits<double>::infinity();
        return STEPS[k].lengthVoxels * 0.5 * (double(weight[u]) + double(weight[v]));
    }
};

/// The minimal cost by a plain binary-heap Dijkstra, independent of route_search.h.
double referenceCost(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, const Costs& costs,
                     Slot source, Slot target)
{
    std::vector<double> dist(index.slotCount(), std::numeric_limits<double>::infinity());
    using Entry = std::pair<double, Slot>;
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> heap;
    dist[source] = 0.0;
    heap.push({0.0, source});
    while (!heap.empty()) {
        const auto [d, u] = heap.top();
        heap.pop();
        if (d > dist[u]) continue;
        if (u == target) return d;
        index.forEachNeighbour(u, [&](Slot v, int k) {
            if (!allowed[v]) return;
            const double nd = d + costs(u, v, k);
            if (nd < dist[v]) {
                dist[v] = nd;
                heap.push({nd, v});
            }
        });
    }
    return std::numeric_limits<double>::infinity();
}

Costs randomCosts(const LumenIndex& index, unsigned seed, double lo, double hi)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(lo, hi);
    Costs c;
    c.weight.assign(index.slotCount(), 0.0f);
    for (Slot s = 0; s < index.slotCount(); ++s)
        if (index.isLumen(s)) c.weight[s] = static_cast<float>(u(rng));
    c.minEdge = lo;
    c.maxEdge = std::sqrt(3.0) * hi;
    return c;
}

/// The route's summed cost; fails the test when it is not a chain of allowed neighbours.
double routeCost(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, const Costs& costs,
                 const std::vector<Slot>& route, const std::string& what)
{
    double sum = 0;
    for (std::size_t i = 0; i < route.size(); ++i) {
        EXPECT_TRUE(allowed[route[i]]) << what << ": route slot " << i << " is not allowed";
        if (i == 0) continue;
        int step = -1;
        index.forEachNeighbour(route[i - 1], [&](Slot t, int k) {
            if (t == route[i]) step = k;
        });
        EXPECT_GE(step, 0) << what << ": route slots " << i - 1 << " and " << i << " are not neighbours";
        if (step >= 0) sum += costs(route[i - 1], route[i], step);
    }
    return sum;
}

/// Both searches on one lumen: same minimal cost, a valid route, the same route on 1 and 2
/// threads; with rounds of the default size and of a few slots (the ends then meet after many
/// rounds, and the stopping rule decides). Returns the route's length in slots.
std::size_t expectSameCost(const LumenIndex& index, const std::vector<std::uint8_t>& allowed, const Costs& costs,
                           Slot source, Slot target, const std::string& what)
{
    route_search::SlotArray<double> dist;
    route_search::SlotArray<Slot> prev;
    const double minimal = referenceCost(index, allowed, costs, source, target);
    EXPECT_LT(minimal, std::numeric_limits<double>::infinity()) << what << ": the reference found no route";
    const bool reached = route_search::dijkstra<1>(index, allowed, source, target, costs, costs.minEdge,
                                                   costs.maxEdge, dist, prev, nullptr);
    EXPECT_TRUE(reached) << what << ": the search from one end found no route";
    if (reached) {
        EXPECT_NEAR(dist[target], minimal, 1e-9 * minimal)
            << what << ": expected the reference's minimal cost " << minimal << " from dijkstra(), saw " << dist[target];
    }
    std::size_t length = 0;
    for (std::size_t roundSlots : {route_search::ROUND_SLOTS, std::size_t(40), std::size_t(300)}) {
        std::ostringstream with;
        with << what << ", rounds of " << roundSlots << " slots";
        std::vector<Slot> routes[2];
        for (int threads : {1, 2}) {
            RouteWorkspace work;
            bool found = false;
            tbb::task_arena(threads).execute([&] {
                found = route_search::shortestRoute<1>(index, allowed, source, target, costs, costs.minEdge,
                                                       costs.maxEdge, work, routes[threads - 1], nullptr,
                                                       route_search::RouteOptions{true, roundSlots});
            });
            EXPECT_TRUE(found) << with.str() << ", " << threads << " thread(s): no route";
        }
        const std::vector<Slot>& route = routes[1];
        EXPECT_EQ(routes[0], routes[1]) << with.str() << ": the route depends on the thread count";
        if (route.empty()) continue;
        EXPECT_EQ(route.front(), source) << with.str();
        EXPECT_EQ(route.back(), target) << with.str();
        const double cost = routeCost(index, allowed, costs, route, with.str());
        EXPECT_NEAR(cost, minimal, 1e-9 * minimal)
            << with.str() << ": expected the reference's minimal cost " << minimal << ", saw " << cost;
        length = route.size();
    }
    {  // from the source alone
        RouteWorkspace work;
        std::vector<Slot> route;
        EXPECT_TRUE(route_search::shortestRoute<1>(index, allowed, source, target, costs, costs.minEdge, costs.maxEdge,
                                                   work, route, nullptr, route_search::RouteOptions{false}))
            << what << ", one end: no route";
        if (!route.empty()) {
            EXPECT_EQ(route.front(), source) << what;
            EXPECT_EQ(route.back(), target) << what;
            const double cost = routeCost(index, allowed, costs, route, what + ", one end");
            EXPECT_NEAR(cost, minimal, 1e-9 * minimal) << what << ", one end";
        }
    }
    return length;
}

TEST(RouteSearch, BothEndsFindTheMinimalCostThroughABlockWithRandomWalls)
{
    for (unsigned seed = 1; seed <= 6; ++seed) {
        std::mt19937 rng(seed);
        std::uniform_real_distribution<double> u(0.0, 1.0);
        // Walls across x with random holes: many routes of different costs.
        std::vector<std::vector<std::uint8_t>> holes(7, std::vector<std::uint8_t>(24 * 24, 0));
        for (auto& wall : holes)
            for (int h = 0; h < 5; ++h) {
                const int j = int(u(rng) * 21), k = int(u(rng) * 21);
                for (int dj = 0; dj < 3; ++dj)
                    for (int dk = 0; dk < 3; ++dk) wall[(j + dj) * 24 + k + dk] = 1;
            }
        const LumenIndex index = boxLumen(80, 24, 24, [&](int i, int j, int k) {
            return i % 12 != 6 || holes[i / 12][j * 24 + k];
        });
        Costs costs = randomCosts(index, seed, 1.0, 8.0);
        if (seed % 2 == 0) costs.noDiagonalAbove = 4.0;  // edges of infinite cost
        const std::vector<std::uint8_t> allowed = lumenSlots(index);
        const Slot source = slotAt(index, {0, 1, 2}), target = slotAt(index, {79, 22, 21});
        ASSERT_NE(source, NO_SLOT);
        ASSERT_NE(target, NO_SLOT);
        std::ostringstream what;
        what << "block with walls, seed " << seed << (seed % 2 == 0 ? ", no diagonal steps between weights > 4" : "");
        EXPECT_GT(expectSameCost(index, allowed, costs, source, target, what.str()), 79u) << what.str();
    }
}

TEST(RouteSearch, BothEndsFindTheMinimalCostAlongALongTubeOverManyRounds)
{
    // 200k voxels: several rounds of route_search::ROUND_SLOTS per end before the ends meet.
    const LumenIndex index = boxLumen(12, 12, 1400, [](int, int, int) { return true; });
    ASSERT_GT(index.slotCount(), 4 * route_search::ROUND_SLOTS);
    for (unsigned seed = 1; seed <= 3; ++seed) {
        const Costs costs = randomCosts(index, seed, 0.5, 3.0);
        std::vector<std::uint8_t> allowed(index.slotCount(), 0);
        for (Slot s = 0; s < index.slotCount(); ++s) {  // seed 3: a long wall with a gap at y >= 10
            const openvdb::Coord c = index.coord(s);
            const bool wall = seed == 3 && c.x() == 6 && c.y() < 10 && c.z() >= 100 && c.z() < 1300;
            allowed[s] = index.isLumen(s) && !wall;
        }
        const Slot source = slotAt(index, {0, 0, 0}), target = slotAt(index, {11, 11, 1399});
        std::ostringstream what;
        what << "tube, seed " << seed;
        EXPECT_GT(expectSameCost(index, allowed, costs, source, target, what.str()), 1399u) << what.str();
    }
}

TEST(RouteSearch, NoRouteBetweenTwoPiecesAndTheSourceAloneWhenItIsTheTarget)
{
    const LumenIndex index = boxLumen(40, 6, 6, [](int i, int, int) { return i != 20; });
    const Costs costs = randomCosts(index, 7, 1.0, 2.0);
    const std::vector<std::uint8_t> allowed = lumenSlots(index);
    const Slot a = slotAt(index, {0, 0, 0}), b = slotAt(index, {39, 5, 5});
    RouteWorkspace work;
    std::vector<Slot> route{1, 2, 3};
    EXPECT_FALSE(route_search::shortestRoute<1>(index, allowed, a, b, costs, costs.minEdge, costs.maxEdge, work,
                                                route, nullptr))
        << "expected no route across the gap at x = 20";
    EXPECT_TRUE(route.empty()) << "expected an empty route when there is none, saw " << route.size() << " slots";
    ASSERT_TRUE(route_search::shortestRoute<1>(index, allowed, a, a, costs, costs.minEdge, costs.maxEdge, work,
                                               route, nullptr));
    EXPECT_EQ(route, std::vector<Slot>{a});
}

TEST(RouteSearch, AWeightRangeTooWideForTheRingTakesTheHeapWithTheSameCost)
{
    const LumenIndex index = boxLumen(30, 10, 10, [](int, int, int) { return true; });
    Costs costs = randomCosts(index, 3, 1e-3, 1e4);
    ASSERT_EQ(route_search::ringWidth(costs.minEdge, costs.maxEdge), 0.0) << "expected a range that needs the heap";
    const std::vector<std::uint8_t> allowed = lumenSlots(index);
    expectSameCost(index, allowed, costs, slotAt(index, {0, 0, 0}), slotAt(index, {29, 9, 9}), "wide weight range");
}

struct CancelledProgress : Progress {
    void update(double, const std::string&) override {}
    bool cancelled() const override { return true; }
};

TEST(RouteSearch, ACancelledSearchThrowsAndEitherSidesFailureReachesTheCaller)
{
    const LumenIndex index = boxLumen(30, 10, 10, [](int, int, int) { return true; });
    const Costs costs = randomCosts(index, 5, 1.0, 2.0);
    const std::vector<std::uint8_t> allowed = lumenSlots(index);
    CancelledProgress cancelled;
    RouteWorkspace work;
    std::vector<Slot> route;
    EXPECT_THROW(route_search::shortestRoute<1>(index, allowed, slotAt(index, {0, 0, 0}), slotAt(index, {29, 9, 9}),
                                                costs, costs.minEdge, costs.maxEdge, work, route, &cancelled),
                 Cancelled);
    for (int threads : {1, 2}) {
        tbb::task_arena(threads).execute([&] {
            route_search::SideBySide sides;
            int ran = 0;
            EXPECT_THROW(sides.run([&] { ++ran; }, [] { throw InputError("there"); }), InputError) << threads;
            EXPECT_THROW(sides.run([] { throw ParameterError("here"); }, [&] { ++ran; }), ParameterError) << threads;
            sides.run([&] { ++ran; }, [&] { ++ran; });
            EXPECT_EQ(ran, 4) << threads << " thread(s): expected every job to run once, even beside a failure";
        });
    }
}

} // namespace
} // namespace flyover
