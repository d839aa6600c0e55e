/// @file object_pool.h
/// @brief Scratch objects lent to one task at a time, for parallel loops whose bodies run
///        nested parallel loops.
///
/// tbb::enumerable_thread_specific gives a thread the same object in every task it runs; but
/// a thread that waits for a nested parallel loop may take up another task of the outer loop
/// meanwhile, which would then use the object the waiting task is still using. A pool lends
/// each task its own: the first free one, or a new one when none is free.
#pragma once

#include <functional>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

namespace flyover {

template <typename T> class ObjectPool {
public:
    explicit ObjectPool(std::function<T()> make) : mMake(std::move(make)) {}
    ObjectPool(const ObjectPool&) = delete;
    ObjectPool& operator=(const ObjectPool&) = delete;

    /// An object lent to the holder until the lease ends.
    class Lease {
    public:
        Lease(ObjectPool& pool, T* object) : mPool(pool), mObject(object) {}
        Lease(const Lease&) = delete;
        Lease& operator=(const Lease&) = delete;
        ~Lease() { mPool.giveBack(mObject); }
        T& operator*() const { return *mObject; }
        T* operator->() const { return mObject; }

    private:
        ObjectPool& mPool;
        T* mObject;
    };

    Lease take()
    {
        {
            std::lock_guard<std::mutex> lock(mMutex);
            if (!mFree.empty()) {
                T* object = mFree.back();
                mFree.pop_back();
                return Lease(*this, object);
            }
        }
        auto made = std::make_unique<T>(mMake());  // outside the lock: making one may be slow
        T* object = made.get();
        std::lock_guard<std::mutex> lock(mMutex);
        mAll.push_back(std::move(made));
        return Lease(*this, object);
    }

    /// Calls f(object) for every object made, in the order made; no lease may be held.
    template <typename F> void forEach(F&& f) const
    {
        for (const auto& object : mAll) f(*object);
    }

    std::size_t size() const { return mAll.size(); }

private:
    void giveBack(T* object)
    {
        std::lock_guard<std::mutex> lock(mMutex);
        mFree.push_back(object);
    }

    std::function<T()> mMake;
    std::mutex mMutex;
    std::vector<std::unique_ptr<T>> mAll;
    std::vector<T*> mFree;
};

} // namespace flyover
