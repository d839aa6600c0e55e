/// @file view_study.h
/// @brief A study loaded once for the interactive viewer (`flyover view`): the surface as an
///        Embree scene, the centerline, the render stage's parameters (from manifest.json),
///        coverage's missed regions and, when there is one, the HU grid for CT slices. Renders
///        fly-over / fly-through pairs, picks pixels, finds the pose that shows a world point,
///        renders the overview and samples slices, with the same camera and render code as the
///        render stage: the same pose gives the same pixels as frames/pair_NNNN.png.
///        Thread-safe: every const method may be called from many threads at once.
#pragma once

#include "colon/params.h"
#include "render/camera.h"
#include "render/overview.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "volume/centerline_types.h"
#include "volume/ct_slice.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>

#include <array>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace flyover {

/// A camera pose of the viewer, as the HTTP API names it.
struct ViewPose {
    double arcMm = 0;                ///< arc length from the rectum end of the centerline (mm)
    double rollDeg = 0;              ///< roll of both cameras about the centerline (degrees)
    std::string direction = "right"; ///< "right": travel rectum -> cecum appears left to right; "left": the opposite
    std::string mode = "flyover";    ///< "flyover" (two OST cameras) or "flythrough" (forward | backward)
    double clipOffsetFraction = 0.5; ///< near plane at d - fraction * D(p); < 0: the study's own clip setting
    int px = 512;                    ///< size of each (square) view in pixels
};

struct PairRender {
    RgbImage image;                  ///< the two views side by side (2 px + gap) x px
    std::array<Camera, 2> cameras;
    std::size_t centerlineIndex = 0;
    nlohmann::json poseJson;         ///< the pose used, with both cameras (LPS mm)
};

struct PickResult {
    bool hit = false;
    Vec3d pointMm;
    double distanceMm = 0;  ///< from the camera to the hit point
    uint32_t triangle = 0;
};

struct LocateResult {
    ViewPose pose;
    int view = 0;
    double x = 0, y = 0;    ///< image coordinates in that view (pixel i spans [i, i+1))
    std::size_t centerlineIndex = 0;
};

class ViewStudy {
public:
    /// Checks that the study holds what the viewer needs (surface.ply, centerline.json) and
    /// reads the small files; the surface and the CT grid are loaded by load() (or in the
    /// background by startLoading()). @throw InputError naming what is missing and the
    /// `flyover run` command that makes it.
    ViewStudy(const std::string& studyDir, const std::string& ctPath = "");
    ~ViewStudy();
    ViewStudy(const ViewStudy&) = delete;
    ViewStudy& operator=(const ViewStudy&) = delete;

    /// Loads the surface (and the CT grid when there is one) in a background thread;
    /// every render waits for it. loadError() reports a failure.
    void startLoading();
    /// Loads synchronously (tests, bench). @throw InputError.
    void load();
    /// Blocks until loading has finished; @throw InputError when it failed.
    void waitLoaded() const;
    /// Before loading: take `previous`'s loaded surface scene (when `surface`) and CT grid (when
    /// `ct` and both read the same CT source) instead of reading their files again (LiveStudy,
    /// for files it saw unchanged). @throw InputError when `previous` failed to load.
    void reuse(const ViewStudy& previous, bool surface, bool ct);
    /// True once loading has finished (successfully or not).
    bool loaded() const;
    /// "" while loading or after success, else the one-line reason.
    std::string loadError() const;

    const std::string& studyDir() const { return mDir; }
    const Centerline& centerline() const { return mCenterline; }
    const RenderParams& renderParams() const { return mParams; }
    double arcMaxMm() const;
    double stepMm() const;
    bool hasCt() const { return !mCtSource.empty(); }
    int maxPx() const { return 2048; }

    /// The `GET /api/study` document (see README "Viewer").
    nlohmann::json studyJson() const;

    /// Centerline index of an arc length. @throw ParameterError (out of range: RangeError).
    std::size_t indexOfArc(double arcMm) const;
    /// The two cameras of a pose (flyover: the render stage's pair; flythrough: forward |
    /// backward, swapped for direction "left").
    std::array<Camera, 2> cameras(const ViewPose& pose, std::size_t* index = nullptr) const;
    PairRender renderPair(const ViewPose& pose) const;
    /// The surface point seen at (x, y) of view 0 or 1 (the OST rule and near plane of the render).
    PickResult pick(const ViewPose& pose, int view, double x, double y) const;
    /// The pose that shows `pointMm` best: nearest centerline point, roll that centres it in
    /// one of the two views; px = image size for x, y.
    LocateResult locate(const Vec3d& pointMm, int px, const std::string& direction) const;

    /// The anterior OST overview of the whole colon at px x px, with the marker at arcMm (< 0: none)
    /// and `marks` (findings) drawn over it.
    RgbImage overview(int px, double markerArcMm, const std::vector<OverviewMarker>& marks = {}) const;
    Camera overviewCamera() const;
    /// The overview pixel's hit and its nearest centerline point.
    struct OverviewPick {
        bool hit = false;
        Vec3d pointMm;
        double arcMm = 0;
    };
    OverviewPick overviewPick(int px, double x, double y) const;

    /// An axis-aligned CT slice through pointMm in radiological display. @throw InputError without CT.
    SliceImage slice(const std::string& plane, const Vec3d& pointMm, double window, double level) const;

    /// Nearest centerline index to a world point (non-bridged points preferred).
    std::size_t nearestIndex(const Vec3d& pointMm) const;
    /// Before loading: leave the CT out of this study (LiveStudy serves a study being computed
    /// without it first, so that the fly-over shows before the CT grid is read).
    void leaveOutCt() { mCtSource.clear(); }
    /// Before loading: build the surface's scene with Embree's fast (Morton) BVH: the same hits,
    /// 2-3x quicker to build, 5-12% slower to trace (view_bench); LiveStudy's first revision of
    /// a study being computed, replaced at the next one.
    void buildSceneFast() { mFastScene = true; }
    bool sceneBuiltFast() const { return mFastScene; }
    /// Whether both serve the very same loaded surface scene (reuse() took it over).
    bool sharesSurfaceWith(const ViewStudy& other) const;
    /// Rough bytes held by the scene and grids (for the bench).
    std::size_t sceneBytes() const;

private:
    FlyoverParams flyoverParams(const ViewPose& pose) const;
    RenderOptions renderOptions(int px) const;
    /// The loop window of a fly-over view at centerline index `index` (inactive without owners
    /// or for the fly-through).
    LoopWindow loopWindow(std::size_t index, const std::string& mode) const;
    double frameRadius(std::size_t index, double rollDeg) const;
    void loadNow();
    const RayScene& scene() const;
    openvdb::FloatGrid::ConstPtr ctGrid() const;

    std::string mDir;
    std::string mCtSource;  ///< ct.vdb of the study or --ct FILE; "" = no CT
    Centerline mCenterline;
    RenderParams mParams;
    nlohmann::json mCoverage;  ///< coverage.json or null
    std::string mRunHint;      ///< the `flyover run` command of this study

    std::shared_ptr<const RayScene> mScene;
    /// Loop-local OST: each scene triangle's owner on the path (render/loop_ownership.h),
    /// computed at load as the render stage computes it; empty when render.loop_reach_mm is 0.
    std::vector<float> mOwners;
    openvdb::FloatGrid::Ptr mCt;
    std::shared_ptr<const RayScene> mReusedScene;  ///< reuse(): taken instead of surface.ply
    openvdb::FloatGrid::Ptr mReusedCt;             ///< reuse(): taken instead of reading the CT
    bool mFastScene = false;                       ///< buildSceneFast()
    std::array<double, 3> mCtSpacing{};
    Vec3d mCtMin, mCtMax;
    std::thread mLoader;
    mutable std::mutex mLoadMutex;
    mutable std::condition_variable mLoadedCv;
    bool mLoaded = false;
    std::string mLoadError;

    mutable std::mutex mCacheMutex;
    mutable std::map<std::pair<std::size_t, long long>, double> mRadiusCache;  ///< (index, roll in µdeg) -> R
    mutable std::map<int, std::shared_ptr<const RgbImage>> mOverviewCache;     ///< px -> unmarked overview
};

/// A parameter in range by type but outside what the study allows (HTTP 422).
struct RangeError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

} // namespace flyover
