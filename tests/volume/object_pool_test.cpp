#include "volume/object_pool.h"

#include <gtest/gtest.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <set>

namespace flyover {
namespace {

// A lease held while another is taken (a nested task on the same thread) gets another object;
// objects given back are lent again instead of new ones made.
TEST(ObjectPool, NestedLeasesGetDistinctObjectsAndFreedOnesAreReused)
{
    int made = 0;
    ObjectPool<int> pool([&] { return ++made; });
    {
        const auto outer = pool.take();
        const auto inner = pool.take();
        EXPECT_NE(&*outer, &*inner) << "two leases held at once share one object";
        EXPECT_EQ(made, 2);
    }
    {
        const auto again = pool.take();
        EXPECT_EQ(made, 2) << "a freed object was not reused";
    }
    std::set<const int*> seen;
    pool.forEach([&](const int& v) { seen.insert(&v); });
    EXPECT_EQ(seen.size(), 2u);
}

// Under nested parallel loops on many threads, no object is ever used by two tasks at once.
TEST(ObjectPool, NoObjectIsLentTwiceAtOnceUnderNestedParallelism)
{
    struct Slot {
        std::atomic<int> users{0};
        Slot() = default;
        Slot(const Slot&) {}
    };
    ObjectPool<Slot> pool([] { return Slot{}; });
    std::atomic<int> clashes{0};
    tbb::task_arena arena(8);
    arena.execute([&] {
        tbb::parallel_for(0, 200, [&](int) {
            const auto lease = pool.take();
            if (lease->users.fetch_add(1) != 0) ++clashes;
            tbb::parallel_for(0, 64, [](int) {});  // a nested loop: its waits may run other outer tasks
            lease->users.fetch_sub(1);
        });
    });
    EXPECT_EQ(clashes.load(), 0) << "an object was lent to two tasks at once";
    EXPECT_LE(pool.size(), 200u);
}

} // namespace
} // namespace flyover
