/// @file coverage.h
/// @brief How much of the lumen surface a navigation method shows. Primary rays of every view
///        along the centerline mark the triangles they hit; coverage is the area of the
///        triangles hit at least once over the total area, for the fly-over (both cameras) and
///        the fly-through (forward, backward, and the two together). Edge-connected triangles
///        never hit form the missed regions, reported with area, centroid and the nearest
///        centerline point. No file I/O.
///
/// Sampling: a triangle smaller than a ray's footprint on the surface can be missed between
/// rays although it is in view, which makes counting only the triangles hit pessimistic, and
/// it converges slowly with the resolution (bench/render_bench --mode coverage). A pixel
/// integrates over its footprint, so each ray also marks the triangles within its footprint:
/// those within half the ray spacing at the hit's depth of the hit point (stretched by 1/cos of
/// the incidence, at most 4x), reached from the hit triangle over shared edges and facing the
/// camera. The walk over the mesh, not through space, keeps a fold's hidden side unmarked.
#pragma once

#include "render/camera.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "volume/centerline_types.h"
#include "volume/progress.h"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

namespace flyover {

struct CoverageParams {
    int viewPx = 192;               ///< coverage rays per view: viewPx x viewPx (pixels, 8..4096)
    double stepMm = 1.0;            ///< distance between views along the centerline (mm, > 0)
    FlyoverParams flyover;          ///< the fly-over cameras (fov, roll, clip offset) as rendered
    bool ost = true;                ///< one-sided transparency for the fly-over rays
    double flythroughFovDeg = 90.0; ///< field of view of the fly-through cameras (degrees)
    bool flythrough = true;         ///< also the fly-through (false: its results stay empty)
    /// Count, with each ray's triangle, the triangles within its footprint (see the file
    /// comment); false: only the triangle each ray hits.
    bool footprint = true;
    double minRegionMm2 = 10.0;     ///< missed regions smaller than this are not listed (mm^2)
    /// The fly-over cameras' framed half-widths, one per centerline point, when the caller has
    /// them (flyoverFrameRadii() with the same `flyover`); empty: computed here.
    std::vector<double> frameRadiiMm;
    /// Loop-local OST for the fly-over (and review) views: each triangle's owner on the path
    /// (triangleOwners()) and the reach (RenderParams::loopReachMm); null or 0: off. A view
    /// then counts only what it shows of its own stretch of colon.
    const std::vector<float>* ownerArcMm = nullptr;
    double loopReachMm = 0.0;
    /// The loop window of a fly-over view at centerline index `index`.
    LoopWindow loopAt(std::size_t index, double centerlineStepMm) const
    {
        LoopWindow w;
        w.ownerArcMm = ownerArcMm;
        w.reachMm = loopReachMm;
        w.arcMm = double(index) * (centerlineStepMm > 0 ? centerlineStepMm : 1.0);
        return w;
    }
};

/// A connected set of triangles that no ray of a method hit.
struct MissedRegion {
    double areaMm2 = 0;
    Vec3d centroidMm;                   ///< area-weighted mean of the triangle centroids
    std::size_t triangles = 0;
    std::size_t nearestCenterlineIndex = 0;
    double arcMm = 0;                   ///< arc length of that centerline point (index * step)
    double distanceToCenterlineMm = 0;  ///< from the centroid to that point
};

struct MethodCoverage {
    std::vector<uint8_t> seen;  ///< per triangle: 1 when hit by at least one ray
    double seenAreaMm2 = 0;
    double fraction = 0;        ///< seenAreaMm2 / total area
    std::vector<MissedRegion> missed;  ///< regions >= minRegionMm2, largest first
    double missedInListedRegionsMm2 = 0;
};

struct CoverageResult {
    double totalAreaMm2 = 0;    ///< the wall to see: without a left-out branch's
    double leftOutAreaMm2 = 0;  ///< the wall round a left-out branch (triangleGeometry)
    std::size_t positions = 0;  ///< centerline points with views
    uint64_t rays = 0;          ///< all rays traced
    MethodCoverage flyover;            ///< both fly-over cameras
    MethodCoverage flythroughForward;  ///< one-way fly-through, rectum -> cecum
    MethodCoverage flythroughBackward; ///< one-way fly-through, cecum -> rectum
    MethodCoverage flythroughTwoWay;   ///< union of both directions
};

/// Per-triangle results are in the scene's triangle order (the mesh's face order).
/// @throw ParameterError for parameters out of range; InputError for an empty centerline
CoverageResult computeCoverage(const RayScene& scene, const Centerline& centerline, const CoverageParams& params,
                               Progress* progress = nullptr);

/// Nearest centerline point of any world position, by a uniform grid over the points.
/// @note Keeps a reference to the centerline: it must outlive the locator.
class CenterlineLocator {
public:
    /// @throw InputError for an empty centerline
    explicit CenterlineLocator(const Centerline& centerline, double cellMm = 16.0);
    /// @return the index of the centerline point nearest to `pointMm`
    std::size_t nearest(const Vec3d& pointMm) const;

private:
    int64_t key(int64_t i, int64_t j, int64_t k) const;
    const Centerline& mLine;
    double mCell;
    Vec3d mOrigin;
    int64_t mDims[3];
    int64_t mMaxRing = 0;
    std::unordered_map<int64_t, std::vector<std::size_t>> mCells;
};

/// Area (mm^2) and centroid of each triangle of a scene, in triangle order.
struct TriangleGeometry {
    std::vector<double> areaMm2;
    std::vector<Vec3d> centroidMm;
    double leftOutAreaMm2 = 0;  ///< area of the triangles given 0 for a left-out branch
};
/// With `centerline` holding a left-out branch (Centerline::leftOutBranchMm): the triangles
/// whose centroid lies nearer to the branch's axis than to any centerline point, and within
/// three branch radii of it, count 0 mm^2 (they are not the colon's wall: not in the totals,
/// not in missed regions, nothing for a review view to add); their area is leftOutAreaMm2.
TriangleGeometry triangleGeometry(const RayScene& scene, const Centerline* centerline = nullptr);

/// The triangles one view shows, by computeCoverage's rule: each ray's triangle and, with
/// `footprint`, those within its footprint (see the file comment). Keeps scratch buffers, so
/// one marker per thread; copies share the mesh topology (built once) and have their own
/// scratch. Keeps a reference to the scene: it must outlive the marker.
class ViewMarker {
public:
    /// @throw ParameterError for viewPx outside 8..4096
    ViewMarker(const RayScene& scene, int viewPx, bool footprint);
    ViewMarker(const ViewMarker& other);
    ViewMarker& operator=(const ViewMarker&) = delete;
    ~ViewMarker();

    /// Appends the triangles that `camera` (viewPx x viewPx rays, OST when `ost`) shows to
    /// `out`; a triangle may be appended more than once. @return the rays traced
    /// With `loop` (active), walls of other loops are passed through (loop-local OST).
    uint64_t mark(const Camera& camera, bool ost, std::vector<uint32_t>& out, const LoopWindow& loop = {});
    /// The same triangles, flagged: seen[f] = 1 for each (`seen` has one byte per triangle of
    /// the scene). @return the rays traced
    uint64_t mark(const Camera& camera, bool ost, uint8_t* seen, const LoopWindow& loop = {});

    struct Topology;
    const Topology& topology() const { return *mTopology; }

private:
    const RayScene& mScene;
    int mViewPx;
    bool mFootprint;
    std::shared_ptr<const Topology> mTopology;
    /// mark() with `shown(begin, end)` called for each run of triangles shown.
    template <typename Shown>
    uint64_t markWith(const Camera& camera, bool ost, const LoopWindow& loop, const Shown& shown);
    struct Scratch;
    std::unique_ptr<Scratch> mScratch;
};

/// Fills `m.seenAreaMm2`, `m.fraction` and `m.missed` from `m.seen` (one flag per triangle of
/// the scene), as computeCoverage does for each method; `regionTriangles`, when given, gets the
/// triangles of each listed region, in the order of `m.missed`.
/// @throw ParameterError when m.seen has the wrong size; InputError for an empty centerline
void summariseCoverage(MethodCoverage& m, const RayScene& scene, const Centerline& centerline, double minRegionMm2,
                       std::vector<std::vector<uint32_t>>* regionTriangles = nullptr);

} // namespace flyover
