#include "pipeline/speculative_mesh.h"

#include "volume/progress.h"
#include "volume/segment.h"

namespace flyover {

namespace {

/// No progress shown (the stage has not started); cancelled when the cut changed the lumen.
class CancelFlag : public Progress {
public:
    explicit CancelFlag(const std::atomic<bool>& flag) : mFlag(flag) {}
    void update(double, const std::string&) override {}
    bool cancelled() const override { return mFlag.load(std::memory_order_relaxed); }

private:
    const std::atomic<bool>& mFlag;
};

} // namespace

SpeculativeMesh::SpeculativeMesh(const openvdb::FloatGrid& sdf, const MeshParams& params, bool deferFinalChecks)
    : SpeculativeMesh(openvdb::FloatGrid::ConstPtr(sdf.deepCopy()), params, deferFinalChecks)
{
}

SpeculativeMesh::SpeculativeMesh(openvdb::FloatGrid::ConstPtr copy, const MeshParams& params, bool deferFinalChecks)
{
    mResult = std::async(std::launch::async, [this, copy, params, deferFinalChecks] {
        CancelFlag progress(mCancel);
        return makeLumenSurface(*copy, params, &mReport, &progress, true, deferFinalChecks);
    });
}

SpeculativeMesh::~SpeculativeMesh()
{
    mCancel = true;
    if (mResult.valid()) mResult.wait();
}

bool SpeculativeMesh::applicable(const openvdb::FloatGrid& sdf) { return !sdf.tree().hasActiveTiles(); }

TriMesh SpeculativeMesh::take(LumenSurfaceReport& report)
{
    TriMesh mesh = mResult.get();
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
{
    const CenterlineParams traced = centerlineParamsFor(*copy, params, mFromTube);
    mResult = std::async(std::launch::async, [this, copy, traced] {
        CancelFlag progress(mCancel);
        return extractCenterline(*copy, traced, &progress, &mReport);
    });
}

SpeculativeCenterline::~SpeculativeCenterline()
{
    mCancel = true;
    if (mResult.valid()) mResult.wait();
}

Centerline SpeculativeCenterline::take(CenterlineReport& report, bool& fromTube)
{
    Centerline c = mResult.get();
    report = mReport;
    fromTube = mFromTube;
    return c;
}

SpeculativeSegmentation::SpeculativeSegmentation(openvdb::FloatGrid::ConstPtr hu, const SegmentParams& params)
{
    mResult = std::async(std::launch::async, [this, hu, params] {
        CancelFlag progress(mCancel);
        return segmentLumen(*hu, params, &progress);
    });
}

SpeculativeSegmentation::~SpeculativeSegmentation()
{
    mCancel = true;
    if (mResult.valid()) mResult.wait();
}

LumenSegmentation SpeculativeSegmentation::take() { return mResult.get(); }

} // namespace flyover
