// The early nodes of the colon's stage graph (study.cpp's table lists them with their edges):
// work that starts on a result a stage hands on before it ends, for a later stage to take. A
// node that throws leaves no result (runPipeline drops the error): the stage it feeds then does
// the work itself, and reports what fails.
#include "colon/study_run.h"

#include "colon/segment.h"
#include "colon/uncut_lumen.h"
#include "surface/lumen_surface.h"
#include "volume/progress.h"

namespace flyover {

namespace {

/// The node's progress, cancelled once the uncut lumen is superseded (the cut removed voxels).
class UntilSuperseded : public Progress {
public:
    UntilSuperseded(const UncutLumen& lumen, Progress* parent) : mLumen(lumen), mParent(parent) {}
    void update(double fraction, const std::string& what) override { reportProgress(mParent, fraction, what); }
    bool cancelled() const override { return mLumen.superseded.load(std::memory_order_relaxed); }

private:
    const UncutLumen& mLumen;
    Progress* mParent;
};

/// Calls doneReading() on the way out of an early node, thrown or not.
struct ReadingDone {
    explicit ReadingDone(UncutLumen& lumen) : mLumen(lumen) {}
    ~ReadingDone() { mLumen.doneReading(); }
    UncutLumen& mLumen;
};

} // namespace

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

void segmentEarly(StudyRun& run, Progress* progress)
{
    if (!run.state.hu || !run.opt.maskPath.empty()) return;  // ingest reused; a mask's lumen is not the CT's air
    run.state.earlySegmentation =
        std::make_shared<LumenSegmentation>(segmentLumen(*run.state.hu, run.opt.params.segment, progress));
}

void meshUncutLumen(StudyRun& run, Progress* progress)
{
    const std::shared_ptr<UncutLumen> lumen = run.state.uncutLumen;
    if (!lumen) return;
    const ReadingDone done(*lumen);
    UntilSuperseded until(*lumen, progress);
    // Its final checks are left to the mesh stage, which makes them behind the first pair.
    lumen->mesh = makeLumenSurface(lumen->sdf(), run.opt.params.mesh, &lumen->meshReport, &until, true, true);
}

void traceUncutLumen(StudyRun& run, Progress* progress)
{
    const std::shared_ptr<UncutLumen> lumen = run.state.uncutLumen;
    if (!lumen) return;
    const ReadingDone done(*lumen);
    UntilSuperseded until(*lumen, progress);
    const CenterlineParams params = centerlineParamsFor(lumen->sdf(), run.opt.params.centerline, lumen->centerlineFromTube);
    lumen->centerline = extractCenterline(lumen->sdf(), params, &until, &lumen->centerlineReport);
}

void prepareSurfaceEarly(StudyRun& run, Progress*) { run.prepareSurfaceArrays(); }

} // namespace flyover
