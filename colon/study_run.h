/// @file study_run.h
/// @brief What a colon stage body sees of a run: the options, the study folder, and the
///        objects earlier stages of the same run left in memory. Each stage body lives in its
///        own stage_<name>.cpp and returns its report for the manifest; the render steps
///        (frames, flythrough, overviews, video, coverage) share stage_render.cpp.
#pragma once

#include "colon/colon_study.h"
#include "pipeline/ingest_to_vdb.h"
#include "pipeline/json_io.h"
#include "pipeline/stage_run.h"
#include "surface/mesh_types.h"
#include "volume/centerline_types.h"
#include "volume/image_io.h"
#include "volume/ingest.h"
#include "volume/progress.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>
#include <tbb/collaborative_call_once.h>

#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace flyover {

class RayScene;
struct LumenSegmentation;
struct UncutLumen;

/// The surface as the render steps' scenes take it: flat arrays (x, y, z per vertex, three
/// vertex indices per face) and the smooth-shading normals of the whole surface, from which the
/// first pair's scenes of some of its triangles and then the scene of all of them are built.
struct SurfaceArrays {
    std::vector<float> xyz;
    std::vector<uint32_t> triangles;
    std::vector<float> normals;
    double readSurfaceSeconds = 0;  ///< reading surface.ply (0 with the mesh in memory)
    double prepareSeconds = 0;      ///< the arrays from the mesh (or file) and the normals
    bool preparedEarly = false;     ///< by the early node beside the mesh stage's write (prepareSurfaceArrays)
};

/// What every render step renders from: the Embree scene of the surface, the centerline and
/// the framed half-width R(p) of every centerline point for the run's fly-over cameras. Built
/// once per run by whichever render step asks first; the others reuse it.
struct RenderInputs {
    std::unique_ptr<RayScene> scene;
    const Centerline* centerline = nullptr;
    std::vector<double> frameRadii;
    double readSurfaceSeconds = 0, prepareSurfaceSeconds = 0, buildSceneSeconds = 0, readCenterlineSeconds = 0,
           frameRadiiSeconds = 0;
    /// Whether the surface's arrays were prepared beside the mesh stage's write (prepareSurfaceArrays).
    bool surfacePreparedEarly = false;
    /// Loop-local OST: the owner on the path of every scene triangle (render/loop_ownership.h),
    /// empty when render.loop_reach_mm is 0 or OST is off; how many were owned by sight and
    /// by a neighbour, and the seconds it took.
    std::vector<float> ownerArcMm;
    std::size_t ownersBySight = 0, ownersByNeighbour = 0, unowned = 0;
    double ownersSeconds = 0;
    ~RenderInputs();
};

/// The fly-over pairs the frames step rendered in this run, by centerline index: the file in
/// the study's frames/ (committed before any later render step starts). The video takes the
/// pairs whose cameras coincide from there instead of rendering them again.
struct RenderedPairs {
    std::vector<std::size_t> centerlineIndices;  ///< ascending
    std::vector<std::string> files;              ///< same order: absolute paths of the PNGs
};

/// Objects handed from stage to stage in memory within one run.
struct StudyState {
    openvdb::FloatGrid::Ptr hu;
    openvdb::FloatGrid::Ptr sdf;
    std::optional<Centerline> centerline;
    std::optional<TriMesh> mesh;
    std::optional<RenderedPairs> framePairs;  ///< set by the frames step when it ran in this run
    /// The segmentation made from `hu` by the early node beside ingest's write of ct.vdb, for
    /// the segment stage (null: none made).
    std::shared_ptr<LumenSegmentation> earlySegmentation;
    /// The lumen before the contact cut and the mesh and centerline the early nodes made of it,
    /// for the mesh and centerline stages unless the cut superseded it (colon/uncut_lumen.h).
    std::shared_ptr<UncutLumen> uncutLumen;
};

/// The colon's parameters as the engine sees them, held by the run (base-from-member: the
/// engine's StageRun refers to them).
struct ColonParamsHolder {
    explicit ColonParamsHolder(const PipelineParams& p) : paramSet(p) {}
    ColonParamSet paramSet;
};

class StudyRun : private ColonParamsHolder, public StageRun {
public:
    explicit StudyRun(const RunOptions& o) : ColonParamsHolder(o.params), StageRun(o, paramSet), opt(o) {}
    ~StudyRun() override;

    /// The lumen level set: from memory when segment ran in this run, else from lumen.vdb.
    /// Thread-safe (centerline and mesh ask for it at the same time).
    openvdb::FloatGrid::Ptr sdf();

    /// The scene, centerline and frame radii of the render steps: from memory when mesh and
    /// centerline ran in this run, else from surface.ply and centerline.json. Built once, by
    /// the first step that asks (the others wait, or help build it: no TBB deadlock). Takes the
    /// arrays of surfaceArrays() (which is empty afterwards).
    const RenderInputs& renderInputs();
    /// Whether renderInputs() has been built.
    bool renderInputsBuilt() const { return bool(mRender); }

    /// The surface's arrays and normals (once): from the mesh in memory, or from surface.ply.
    /// The frames step builds the first pair's scenes from them before renderInputs() takes
    /// them. Not thread-safe against renderInputs().
    SurfaceArrays& surfaceArrays();
    /// The centerline of the render steps: from memory, else read from centerline.json (once).
    const Centerline& renderCenterline();

    /// surfaceArrays() from state.mesh, when the mesh stage ran in this run (the early node
    /// beside the writing and hashing of surface.ply; a no-op without a mesh in memory).
    void prepareSurfaceArrays();

    const RunOptions& opt;
    StudyState state;

private:
    std::mutex mLoadMutex;
    tbb::collaborative_once_flag mRenderOnce;
    std::unique_ptr<RenderInputs> mRender;
    std::mutex mSurfaceMutex;
    std::unique_ptr<SurfaceArrays> mSurface;
    double mReadCenterlineSeconds = 0;
};


// Stage bodies: each writes its artifacts (atomically) and returns its report.
nlohmann::json runIngest(StudyRun& run, Progress* progress);
nlohmann::json runSegment(StudyRun& run, Progress* progress);
/// The segment stage when the study starts from an external mask (`flyover run --mask FILE
/// [--label N]`, with or without a CT): the lumen is the mask's label, matched to the CT's grid
/// when there is a CT (ct.vdb from ingest), else on the mask's own geometry. The report records
/// the mask's geometry, which `flyover export --lumen` uses when the study has no CT.
nlohmann::json runSegmentFromMask(StudyRun& run, const std::string& maskPath, Progress* progress);
nlohmann::json runCenterline(StudyRun& run, Progress* progress);
struct LumenSegmentation;
/// Finds and cuts the contacts between touching loops in seg's mask and sdf (colon/contacts.h),
/// records them in the sdf's metadata (read by the centerline stage), logs them, returns the
/// report.
nlohmann::json cutLumenContacts(StudyRun& run, LumenSegmentation& seg);
/// The contacts recorded in the lumen level set's metadata by cutLumenContacts, with the arcs
/// of `centerline` nearest to their two sides; null when there are none recorded.
nlohmann::json contactsAlongPath(const openvdb::FloatGrid& sdf, const Centerline& centerline);
nlohmann::json runMesh(StudyRun& run, Progress* progress);
// The early nodes of the colon's graph (stage_early.cpp): each runs when what it reads is
// handed on, and its result waits in run.state for the stage it feeds.
/// segmentLumen on state.hu beside ingest's write of ct.vdb, into state.earlySegmentation.
void segmentEarly(StudyRun& run, Progress* progress);
/// The mesh of state.uncutLumen beside the contact cut (its final checks left to the mesh stage).
void meshUncutLumen(StudyRun& run, Progress* progress);
/// The centerline of state.uncutLumen beside the contact cut.
void traceUncutLumen(StudyRun& run, Progress* progress);
/// run.prepareSurfaceArrays() beside the mesh stage's write of surface.ply.
void prepareSurfaceEarly(StudyRun& run, Progress* progress);
// The render steps: each its own cached step of the graph, side by side after the frames.
/// Fly-over pairs in frames/; the first pair is rendered, written and announced before the
/// rest (log line "first fly-over pair", JSON event "first_pair").
nlohmann::json runFrames(StudyRun& run, Progress* progress);
nlohmann::json runFlythrough(StudyRun& run, Progress* progress);
nlohmann::json runOverviews(StudyRun& run, Progress* progress);
nlohmann::json runVideo(StudyRun& run, Progress* progress);
nlohmann::json runCoverage(StudyRun& run, Progress* progress);
/// Polyp candidates in polyps/ (stage_polyps.cpp): after the frames, beside the render steps.
nlohmann::json runPolyps(StudyRun& run, Progress* progress);

} // namespace flyover
