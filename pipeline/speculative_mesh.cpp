#include "pipeline/speculative_mesh.h"

#include "volume/progress.h"

namespace flyover {

namespace {

/// No progress shown (the mesh stage has not started); cancelled when the cut changed the lumen.
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
{
    openvdb::FloatGrid::Ptr copy = sdf.deepCopy();
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

} // namespace flyover
