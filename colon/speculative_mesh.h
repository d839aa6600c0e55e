/// @file speculative_mesh.h
/// @brief Internal to pipeline/ (issue 15): the lumen surface and the centerline made beside
///        the contact cut. The segment stage's contact search (colon/contacts.h) runs mostly
///        on one thread; the mesh and the centerline do not need its answer unless it cuts. So
///        the segment stage makes one deep copy of the lumen level set before the cut and
///        starts makeLumenSurface() and extractCenterline() on it, each on a thread of its own,
///        and hands them to the mesh and centerline stages only when the cut removed no voxel
///        (the level set's values and topology are then those those stages would read: contacts
///        only add metadata). When something was cut, both are cancelled and the stages work
///        on the cut level set as before. The results are the same either way.
#pragma once

#include "surface/lumen_surface.h"
#include "colon/centerline.h"
#include "volume/progress.h"
#include "colon/segment.h"

#include <openvdb/openvdb.h>

#include <atomic>
#include <exception>
#include <future>
#include <optional>
#include <string>

#include <sys/types.h>

namespace flyover {

/// Work of type T on a thread of its own, given a Progress whose cancelled() turns true when
/// the owner drops it: the destructor cancels (the work stops at its next progress report) and
/// waits. Declare it as the owner's last member, so that it waits before the owner's other
/// members (which the work may write) are destroyed.
template <typename T>
class CancellableWork {
public:
    template <typename Fn>
    explicit CancellableWork(Fn work)
        : mResult(std::async(std::launch::async, [this, work] {
              Flag progress(mCancel);
              return work(&progress);
          }))
    {
    }
    ~CancellableWork()
    {
        mCancel = true;
        if (mResult.valid()) mResult.wait();
    }
    CancellableWork(const CancellableWork&) = delete;
    CancellableWork& operator=(const CancellableWork&) = delete;

    /// Waits for the work and returns its result; rethrows what it threw. Call once.
    T get() { return mResult.get(); }

private:
    /// No progress shown; cancelled once the owner is dropped.
    class Flag : public Progress {
    public:
        explicit Flag(const std::atomic<bool>& flag) : mFlag(flag) {}
        void update(double, const std::string&) override {}
        bool cancelled() const override { return mFlag.load(std::memory_order_relaxed); }

    private:
        const std::atomic<bool>& mFlag;
    };

    std::atomic<bool> mCancel{false};
    std::future<T> mResult;
};

class SpeculativeMesh {
public:
    /// Starts meshing a deep copy of `sdf` with `params` on its own thread; the final checks
    /// are left to the taker (makeLumenSurface's deferFinalChecks) when `deferFinalChecks`.
    SpeculativeMesh(const openvdb::FloatGrid& sdf, const MeshParams& params, bool deferFinalChecks = false);
    /// The same on `copy`, a level set nobody changes (shared with a SpeculativeCenterline).
    /// `yielding`: the mesh takes only the cores the rest of the run leaves idle (its thread
    /// at nice YIELDING_NICE, its parallel loops in a low-priority TBB arena), for a run whose
    /// first pair does not wait for it (local_first_pair.h). The mesh is the same.
    SpeculativeMesh(openvdb::FloatGrid::ConstPtr copy, const MeshParams& params, bool deferFinalChecks,
                    bool yielding = false);
    static constexpr int YIELDING_NICE = 10;
    /// Back to nice 0 once the first pair no longer waits (when the system lets the process
    /// lower a nice value: root, or RLIMIT_NICE); the TBB arena stays low-priority.
    void stopYielding();
    SpeculativeMesh(const SpeculativeMesh&) = delete;
    SpeculativeMesh& operator=(const SpeculativeMesh&) = delete;

    /// Whether `sdf` can be meshed this way: it has no active tiles (the contact cut would
    /// voxelise them, changing the topology that was copied).
    static bool applicable(const openvdb::FloatGrid& sdf);

    /// Waits for the mesh and returns it, its report in `report`; rethrows what meshing
    /// threw. Call once.
    TriMesh take(LumenSurfaceReport& report);

private:
    LumenSurfaceReport mReport;
    std::atomic<pid_t> mThread{0};   ///< the yielding work's thread, once it runs
    std::atomic<bool> mYieldOver{false};  ///< stopYielding() was called (even before the thread ran)
    CancellableWork<TriMesh> mWork;  ///< last: cancelled and waited for before mReport goes
};

/// The parameters the centerline stage traces `sdf` with: `given`, with the rectal tube's tip
/// (recorded by segment in the level set's metadata) as the rectum hint unless `given` has one.
/// `fromTube`: whether the hint is the tube's tip.
CenterlineParams centerlineParamsFor(const openvdb::FloatGrid& sdf, const CenterlineParams& given, bool& fromTube);

class SpeculativeCenterline {
public:
    /// Starts extractCenterline() on `copy` (a level set nobody changes) with the parameters
    /// centerlineParamsFor(*copy, params) on its own thread.
    SpeculativeCenterline(openvdb::FloatGrid::ConstPtr copy, const CenterlineParams& params);
    SpeculativeCenterline(const SpeculativeCenterline&) = delete;
    SpeculativeCenterline& operator=(const SpeculativeCenterline&) = delete;

    /// Waits for the centerline and returns it, its report in `report` and whether its rectum
    /// hint was the rectal tube's tip in `fromTube`; rethrows what tracing threw. Call once.
    Centerline take(CenterlineReport& report, bool& fromTube);
    /// Waits for the centerline and returns it, kept for take() (the segment stage's local
    /// first pair looks at it first). Rethrows what tracing threw.
    const Centerline& result();

private:
    CenterlineReport mReport;
    bool mFromTube = false;
    std::optional<Centerline> mResult;
    std::exception_ptr mError;  ///< what tracing threw, for take() after result()
    CancellableWork<Centerline> mWork;  ///< last: cancelled and waited for before mReport goes
};

/// The CT path's segmentLumen() begun beside the ingest stage's writing and hashing of ct.vdb
/// (a single thread's work, the other core idle): the segment stage takes it when it computes
/// (its key, which needs ct.vdb's digest, is then known); when it is reused from the cache
/// instead, this is cancelled. The segmentation is the same either way (the same HU grid).
class SpeculativeSegmentation {
public:
    /// Starts segmentLumen(*hu, params) on its own thread; nobody changes `hu` meanwhile.
    SpeculativeSegmentation(openvdb::FloatGrid::ConstPtr hu, const SegmentParams& params);
    SpeculativeSegmentation(const SpeculativeSegmentation&) = delete;
    SpeculativeSegmentation& operator=(const SpeculativeSegmentation&) = delete;

    /// Waits for the segmentation and returns it; rethrows what it threw. Call once.
    LumenSegmentation take();

private:
    CancellableWork<LumenSegmentation> mWork;
};

} // namespace flyover
