/// @file stage_context.h
/// @brief What a stage body sees of a run (internal to pipeline/): the options, the study
///        folder, and the objects earlier stages of the same run left in memory. Each stage
///        body lives in its own stage_<name>.cpp and returns its report for the manifest; the
///        render steps (frames, flythrough, overviews, video, coverage) share stage_render.cpp.
#pragma once

#include "pipeline/study.h"
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
#include <future>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace flyover {

class RayScene;
struct LocalFirstPair;
class SpeculativeMesh;
class SpeculativeCenterline;
class SpeculativeSegmentation;
struct PartAnalysis;
struct PartSurface;

/// The surface as the render steps' scenes take it: flat arrays (x, y, z per vertex, three
/// vertex indices per face) and the smooth-shading normals of the whole surface, from which the
/// first pair's scenes of some of its triangles and then the scene of all of them are built.
struct SurfaceArrays {
    std::vector<float> xyz;
    std::vector<uint32_t> triangles;
    std::vector<float> normals;
    double readSurfaceSeconds = 0;  ///< reading surface.ply (0 with the mesh in memory)
    double prepareSeconds = 0;      ///< the arrays from the mesh (or file) and the normals
    bool begunByMeshStage = false;  ///< prepared beside the mesh stage (StudyRun::beginSurfaceArrays)
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
    /// Whether the surface's arrays were prepared beside the mesh stage (beginSurfaceArrays).
    bool surfaceBegunByMeshStage = false;
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
    std::shared_ptr<PartAnalysis> part;          ///< flyover inspect: the voids stage's analysis
    std::shared_ptr<PartSurface> partSurface;    ///< flyover inspect: the surfaces stage's mesh
    std::optional<RenderedPairs> framePairs;  ///< set by the frames step when it ran in this run
    /// Whether this run computes the mesh stage (set by runPipeline): the segment stage then
    /// meshes its lumen beside the contact cut (speculative_mesh.h).
    bool meshWanted = false;
    /// The same for the centerline stage: the segment stage traces its lumen's centerline
    /// beside the contact cut.
    bool centerlineWanted = false;
    /// Whether this run computes a render step: the mesh stage then begins the render scene
    /// (StudyRun::beginSurfaceArrays) as soon as its mesh is in memory.
    bool renderWanted = false;
    /// Whether this run computes the segment stage from the CT: the ingest stage then begins
    /// segmentLumen beside its writing of ct.vdb (speculative_mesh.h).
    bool segmentWanted = false;
    /// That segmentation, for the segment stage (dropped when the stage is reused instead).
    std::shared_ptr<SpeculativeSegmentation> speculativeSegmentation;
    /// The segment stage's mesh of the lumen it handed on, when the contact cut changed nothing.
    std::shared_ptr<SpeculativeMesh> speculativeMesh;
    /// ... and its centerline of that lumen.
    std::shared_ptr<SpeculativeCenterline> speculativeCenterline;
    /// Whether this run goes through the frames step with frames and a mesh that allow a first
    /// pair from a local surface (local_first_pair.h; set by runPipeline): the segment stage
    /// then makes it after the contact cut, and the whole mesh it begins beside the cut yields
    /// the cores to the cut, the centerline and that pair (SpeculativeMesh's `yielding`).
    bool localFirstPairWanted = false;
    /// That pair, when it was certified (and announced), for the frames step.
    std::shared_ptr<const LocalFirstPair> localFirstPair;
    /// What the attempt found (null: none was made), for the frames step's report.
    nlohmann::json localFirstPairReport;
};

class StudyRun {
public:
    explicit StudyRun(const RunOptions& o) : opt(o), dir(o.studyDir), start(std::chrono::steady_clock::now()) {}
    /// Waits for the arrays begun by beginSurfaceArrays() (defined in stage_render.cpp).
    ~StudyRun();

    std::string path(const std::string& name) const { return (dir / name).string(); }

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

    /// The surface's arrays and normals (once): the ones begun by beginSurfaceArrays(), or from
    /// the mesh in memory, or from surface.ply. The frames step builds the first pair's scenes
    /// from them before renderInputs() takes them. Not thread-safe against renderInputs().
    SurfaceArrays& surfaceArrays();
    /// The centerline of the render steps: from memory, else read from centerline.json (once).
    const Centerline& renderCenterline();

    /// Begins preparing surfaceArrays() from state.mesh on a thread of its own (the mesh stage
    /// calls it once its mesh is in memory, before writing and hashing surface.ply). Nobody
    /// changes state.mesh afterwards. It renders nothing: a frames step reused from the cache
    /// builds the scene from it.
    void beginSurfaceArrays();

    /// Work that should not compete with the first pair (the mesh checks made behind, the
    /// fsyncs and records of the write-behind) waits here until the frames step has
    /// announced it and built the whole scene after it, or is reused from the cache, or the stage graph has ended (frames not run
    /// or failed): runPipeline opens the gate then, before it joins the write-behind.
    void waitForFirstPair() { mFirstPairGate.wait(); }
    void openFirstPairGate()
    {
        mFirstPairOutGate.open();
        mFirstPairGate.open();
    }
    /// The write-behind's renames (no CPU, no memory) wait only for the first pair's
    /// announcement, so that an open `flyover view` gets the study at once; opened by the
    /// frames step right after it, and by openFirstPairGate().
    void waitForFirstPairOut() { mFirstPairOutGate.wait(); }
    void openFirstPairOutGate() { mFirstPairOutGate.open(); }

    const RunOptions& opt;
    std::filesystem::path dir;
    StudyState state;
    std::chrono::steady_clock::time_point start;  ///< when runPipeline started

private:
    /// A one-way gate: wait() blocks until open() (called any number of times, any thread).
    class Gate {
    public:
        void wait() const { mOpened.wait(); }
        void open() { std::call_once(mOnce, [this] { mPromise.set_value(); }); }

    private:
        std::once_flag mOnce;
        std::promise<void> mPromise;
        std::shared_future<void> mOpened = mPromise.get_future().share();
    };
    Gate mFirstPairOutGate, mFirstPairGate;
    std::mutex mLoadMutex;
    tbb::collaborative_once_flag mRenderOnce;
    std::unique_ptr<RenderInputs> mRender;
    std::mutex mSurfaceMutex;
    std::unique_ptr<SurfaceArrays> mSurface;
    double mReadCenterlineSeconds = 0;
    /// The arrays begun by beginSurfaceArrays(). Last: its destructor waits for the work, which
    /// reads state.mesh.
    std::future<std::unique_ptr<SurfaceArrays>> mSurfaceBegun;
};

inline nlohmann::json vec3Json(const Vec3d& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

/// Reads run.opt.ctPath into an isotropic grid named `gridName`, writes it to ct.vdb and returns
/// the ingest report (geometry, reader, warnings): the ingest of both `run` and `inspect`.
/// `beforeWrite`, when given, is called with the grid before ct.vdb is written.
nlohmann::json ingestToCtVdb(StudyRun& run, const IngestParams& params, const ImageReadOptions& options,
                             const std::string& gridName, Progress* progress, openvdb::FloatGrid::Ptr& grid,
                             const std::function<void(const openvdb::FloatGrid::Ptr&)>& beforeWrite = {});

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
/// The segment stage's first fly-over pair from the surface round the first centerline point
/// of `centerline` (local_first_pair.h): when certified, written alone into frames/, announced
/// (log line, JSON event "first_pair") and kept in run.state for the frames step. Returns what
/// the attempt found (run.state.localFirstPairReport).
nlohmann::json makeLocalFirstPair(StudyRun& run, const openvdb::FloatGrid& sdf, const Centerline& centerline);
// The render steps: each its own cached step of the graph, side by side after the frames.
/// Fly-over pairs in frames/; the first pair is rendered, written and announced before the
/// rest (log line "first fly-over pair", JSON event "first_pair").
nlohmann::json runFrames(StudyRun& run, Progress* progress);
nlohmann::json runFlythrough(StudyRun& run, Progress* progress);
nlohmann::json runOverviews(StudyRun& run, Progress* progress);
nlohmann::json runVideo(StudyRun& run, Progress* progress);
nlohmann::json runCoverage(StudyRun& run, Progress* progress);

// The stages of a part study (`flyover inspect`), in stage_inspect.cpp.
nlohmann::json runPartIngest(StudyRun& run, Progress* progress);
nlohmann::json runVoids(StudyRun& run, Progress* progress);
nlohmann::json runPartSurfaces(StudyRun& run, Progress* progress);
nlohmann::json runPartOverviews(StudyRun& run, Progress* progress);
nlohmann::json runTurntable(StudyRun& run, Progress* progress);

} // namespace flyover
