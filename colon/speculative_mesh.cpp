#include "colon/speculative_mesh.h"

#include "volume/progress.h"
#include "colon/segment.h"

#include <tbb/task_arena.h>

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace flyover {

SpeculativeMesh::SpeculativeMesh(const openvdb::FloatGrid& sdf, const MeshParams& params, bool deferFinalChecks)
    : SpeculativeMesh(openvdb::FloatGrid::ConstPtr(sdf.deepCopy()), params, deferFinalChecks)
{
}

SpeculativeMesh::SpeculativeMesh(openvdb::FloatGrid::ConstPtr copy, const MeshParams& params, bool deferFinalChecks,
                                 bool yielding)
    : mWork([this, copy, params, deferFinalChecks, yielding](Progress* progress) {
          if (!yielding) return makeLumenSurface(*copy, params, &mReport, progress, true, deferFinalChecks);
          // This thread at nice 10 (Linux: a thread's own) and its parallel loops in a
          // low-priority arena, whose tasks TBB's workers take only when no other arena has
          // work: the mesh goes on in what the cut, the centerline and the first pair leave.
          mThread = pid_t(::syscall(SYS_gettid));
          if (!mYieldOver) {
              ::setpriority(PRIO_PROCESS, id_t(mThread.load()), YIELDING_NICE);
              if (mYieldOver) ::setpriority(PRIO_PROCESS, id_t(mThread.load()), 0);  // stopYielding came between
          }
          tbb::task_arena arena(tbb::task_arena::automatic, 1, tbb::task_arena::priority::low);
          return arena.execute([&] { return makeLumenSurface(*copy, params, &mReport, progress, true, deferFinalChecks); });
      })
{
}

void SpeculativeMesh::stopYielding()
{
    // Best effort: lowering a nice value needs CAP_SYS_NICE or RLIMIT_NICE (root has both);
    // refused, the thread stays at nice 10, which matters only against other processes.
    mYieldOver = true;
    const pid_t thread = mThread.load();
    if (thread > 0) ::setpriority(PRIO_PROCESS, id_t(thread), 0);
}

bool SpeculativeMesh::applicable(const openvdb::FloatGrid& sdf) { return !sdf.tree().hasActiveTiles(); }

TriMesh SpeculativeMesh::take(LumenSurfaceReport& report)
{
    TriMesh mesh = mWork.get();
    report = mReport;
    return mesh;
}

CenterlineParams centerlineParamsFor(const openvdb::FloatGrid& sdf, const CenterlineParams& given, bool& fromTube)
{
    CenterlineParams params = given;
    fromTube = false;
    if (!params.rectumMm)
        if (const auto tip = sdf.getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META)) {
            params.rectumMm = Vec3d{tip->value()[0], tip->value()[1], tip->value()[2]};
            fromTube = true;
        }
    return params;
}

SpeculativeCenterline::SpeculativeCenterline(openvdb::FloatGrid::ConstPtr copy, const CenterlineParams& params)
    : mWork([this, copy, traced = centerlineParamsFor(*copy, params, mFromTube)](Progress* progress) {
          return extractCenterline(*copy, traced, progress, &mReport);
      })
{
}

const Centerline& SpeculativeCenterline::result()
{
    if (!mResult && !mError) {
        try {
            mResult = mWork.get();
        } catch (...) {
            mError = std::current_exception();
        }
    }
    if (mError) std::rethrow_exception(mError);
    return *mResult;
}

Centerline SpeculativeCenterline::take(CenterlineReport& report, bool& fromTube)
{
    result();  // waits; rethrows what tracing threw
    Centerline c = std::move(*mResult);
    mResult.reset();
    report = mReport;
    fromTube = mFromTube;
    return c;
}

SpeculativeSegmentation::SpeculativeSegmentation(openvdb::FloatGrid::ConstPtr hu, const SegmentParams& params)
    : mWork([hu, params](Progress* progress) { return segmentLumen(*hu, params, progress); })
{
}

LumenSegmentation SpeculativeSegmentation::take() { return mWork.get(); }

} // namespace flyover
