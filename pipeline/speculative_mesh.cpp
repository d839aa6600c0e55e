#include "pipeline/speculative_mesh.h"

#include "volume/progress.h"
#include "volume/segment.h"

namespace flyover {

SpeculativeMesh::SpeculativeMesh(const openvdb::FloatGrid& sdf, const MeshParams& params, bool deferFinalChecks)
    : SpeculativeMesh(openvdb::FloatGrid::ConstPtr(sdf.deepCopy()), params, deferFinalChecks)
{
}

SpeculativeMesh::SpeculativeMesh(openvdb::FloatGrid::ConstPtr copy, const MeshParams& params, bool deferFinalChecks)
    : mWork([this, copy, params, deferFinalChecks](Progress* progress) {
          return makeLumenSurface(*copy, params, &mReport, progress, true, deferFinalChecks);
      })
{
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

Centerline SpeculativeCenterline::take(CenterlineReport& report, bool& fromTube)
{
    Centerline c = mWork.get();
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
