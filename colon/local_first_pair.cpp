#include "colon/local_first_pair.h"

#include "render/ray_scene.h"
#include "surface/lumen_surface.h"
#include "volume/error.h"

#include <openvdb/tools/Clip.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <vector>

namespace flyover {

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

/// Half-width of the exact box in units of the first point's cap = 2 D + 5 mm (the frame radius
/// caps each point's need at 1.05 cap; the far wall of the first stretch lies within ~1.7 cap
/// on the phantoms), and at least MIN_EXACT_HALF_MM (a thin first point).
constexpr double EXACT_HALF_CAPS = 2.0;
constexpr double MIN_EXACT_HALF_MM = 40.0;
/// The clip's margin round the exact box: voxels (rings of the smoothing), and at least mm.
constexpr double MARGIN_VOXELS = 40.0;
constexpr double MIN_MARGIN_MM = 20.0;
/// The level set's leaves are widened by this many voxels for the rays that meet nothing: the
/// surface's vertices lie in cells of its zero crossing, moved by the smoothing by well under
/// a voxel (max 0.48 mm on the full phantom).
constexpr double LEAF_WIDENING_VOXELS = 2.0;
/// Tried only when the clip box holds at most this fraction of the level set's leaves.
constexpr double MAX_CLIP_LEAF_FRACTION = 0.35;

BoxMm boxAround(const Vec3d& c, double half)
{
    return BoxMm{c - Vec3d{half, half, half}, c + Vec3d{half, half, half}};
}

/// The four corners of the camera's near-plane rectangle, where the rays of a w x h image start
/// (pixelDirection at the image's corners, at the near plane's depth).
std::array<Vec3d, 4> nearCorners(const Camera& cam, int widthPx, int heightPx)
{
    std::array<Vec3d, 4> out;
    for (int k = 0; k < 4; ++k)
        out[std::size_t(k)] = cam.position + pixelDirection(cam, widthPx, heightPx, (k & 1) ? widthPx : 0,
                                                              (k & 2) ? heightPx : 0) * cam.nearMm;
    return out;
}

/// A scene of the faces (12 triangles a box) of the active leaves of `sdf` not wholly inside
/// `exact`, widened by LEAF_WIDENING_VOXELS, that a ray of `cams` may meet (frustumTriangles
/// drops the others); `count` gets the number of boxes kept. Null when none is.
std::unique_ptr<RayScene> leafBoxScene(const openvdb::FloatGrid& sdf, const BoxMm& exact,
                                       const std::array<Camera, 2>& cams, const RenderOptions& ro, std::size_t& count)
{
    const openvdb::math::Transform& xf = sdf.transform();
    const double widen = LEAF_WIDENING_VOXELS * xf.voxelSize()[0];
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    static constexpr int FACES[12][3] = {{0, 1, 3}, {0, 3, 2}, {4, 6, 7}, {4, 7, 5}, {0, 4, 5}, {0, 5, 1},
                                         {2, 3, 7}, {2, 7, 6}, {0, 2, 6}, {0, 6, 4}, {1, 5, 7}, {1, 7, 3}};
    for (auto leaf = sdf.tree().cbeginLeaf(); leaf; ++leaf) {
        if (leaf->isEmpty()) continue;
        const openvdb::CoordBBox cb = leaf->getNodeBoundingBox();
        const openvdb::BBoxd wb = xf.indexToWorld(openvdb::BBoxd(cb.min().asVec3d() - openvdb::Vec3d(0.5),
                                                                 cb.max().asVec3d() + openvdb::Vec3d(0.5)));
        const BoxMm box{Vec3d{wb.min()[0] - widen, wb.min()[1] - widen, wb.min()[2] - widen},
                        Vec3d{wb.max()[0] + widen, wb.max()[1] + widen, wb.max()[2] + widen}};
        if (exact.contains(box.min) && exact.contains(box.max)) continue;
        const auto base = uint32_t(xyz.size() / 3);
        for (int k = 0; k < 8; ++k) {
            xyz.push_back(float((k & 1) ? box.max.x : box.min.x));
            xyz.push_back(float((k & 2) ? box.max.y : box.min.y));
            xyz.push_back(float((k & 4) ? box.max.z : box.min.z));
        }
        for (const auto& f : FACES)
            for (int k = 0; k < 3; ++k) tris.push_back(base + uint32_t(f[k]));
    }
    count = 0;
    if (tris.empty()) return nullptr;
    std::vector<uint32_t> seen = frustumTriangles(xyz, tris, {cams[0], cams[1]}, ro.widthPx, ro.heightPx);
    for (std::size_t i = 0; i < seen.size(); i += 3)  // a box's kept faces come together
        count += (i == 0 || seen[i] / 8 != seen[i - 3] / 8) ? 1 : 0;
    if (seen.empty()) return nullptr;
    SceneOptions fast;
    fast.fastBuild = true;
    return std::make_unique<RayScene>(std::move(xyz), std::move(seen), fast);
}

} // namespace

bool localFirstPairApplies(const MeshParams& mesh, const RenderOptions& ro)
{
    const bool decimates =
        mesh.decimateTargetFaces > 0 || mesh.decimateFraction < 1.0 || mesh.decimateMaxErrorVoxels > 0.0;
    return !decimates && ro.supersample == 1;
}

LocalFirstPair localFirstPair(const openvdb::FloatGrid& sdf, const Centerline& centerline, std::size_t index,
                              const MeshParams& mesh, const FlyoverParams& flyover, const RenderOptions& ro)
{
    LocalFirstPair out;
    if (!localFirstPairApplies(mesh, ro)) {
        out.reason = "supersampled frames or a decimated mesh";
        return out;
    }
    if (index >= centerline.points.size()) throw ParameterError("localFirstPair: centerline index past its end");
    const CenterlinePoint& p = centerline.points[index];
    const double cap = 2.0 * std::max(p.radiusMm, 0.0) + 5.0;
    const double exactHalf = std::max(EXACT_HALF_CAPS * cap, MIN_EXACT_HALF_MM);
    const BoxMm exact = boxAround(p.positionMm, exactHalf);
    // Only where the clip box holds a small part of the surface: else the whole mesh is about
    // as near (a small lumen), and the try would only add its own work.
    const double margin = std::max(MARGIN_VOXELS * sdf.transform().voxelSize()[0], MIN_MARGIN_MM);
    const BoxMm clip = boxAround(p.positionMm, exactHalf + margin);
    std::size_t leaves = 0, inClip = 0;
    for (auto leaf = sdf.tree().cbeginLeaf(); leaf; ++leaf) {
        ++leaves;
        const openvdb::Vec3d c = sdf.transform().indexToWorld(leaf->getNodeBoundingBox().getCenter());
        inClip += clip.contains(Vec3d{c[0], c[1], c[2]}) ? 1 : 0;
    }
    out.exactBox = exact;
    out.clipBox = clip;
    out.clipLeafFraction = leaves > 0 ? double(inClip) / double(leaves) : 1.0;
    if (out.clipLeafFraction > MAX_CLIP_LEAF_FRACTION) {
        out.reason = "the box round the first cameras holds most of the surface";
        return out;
    }

    // The surface in the clip box, made as the mesh stage makes the whole one.
    auto t = Clock::now();
    std::unique_ptr<RayScene> scene;
    try {
        const openvdb::BBoxd world(openvdb::Vec3d(clip.min.x, clip.min.y, clip.min.z),
                                   openvdb::Vec3d(clip.max.x, clip.max.y, clip.max.z));
        const openvdb::FloatGrid::Ptr clipped = openvdb::tools::clip(sdf, world);
        LumenSurfaceReport report;
        const TriMesh local = makeLumenSurface(*clipped, mesh, &report, nullptr, false, true);
        std::vector<float> xyz;
        std::vector<uint32_t> tris;
        triMeshArrays(local, xyz, tris);
        out.localTriangles = tris.size() / 3;
        std::vector<float> normals = smoothVertexNormals(xyz, tris);
        SceneOptions fast;
        fast.fastBuild = true;
        scene = std::make_unique<RayScene>(std::move(xyz), std::move(tris), normals, fast);
    } catch (const InputError& e) {  // no surface in the box
        out.reason = std::string("no surface round the first point: ") + e.what();
        return out;
    }
    out.meshSeconds = secondsSince(t);

    t = Clock::now();
    bool fanWithin = false;
    out.frameRadiusMm = flyoverFrameRadiusAt(*scene, centerline, flyover, index, {}, exact, fanWithin);
    out.cameras = flyoverCameras(p, flyover, out.frameRadiusMm);
    out.radiusSeconds = secondsSince(t);
    if (!fanWithin) {
        out.reason = "a fan ray of the frame radius leaves the exact box";
        return out;
    }
    for (const Camera& cam : out.cameras)
        for (const Vec3d& c : nearCorners(cam, ro.widthPx, ro.heightPx))
            if (!exact.contains(c)) {
                out.reason = "a near plane reaches out of the exact box";
                return out;
            }

    t = Clock::now();
    std::array<HitImage, 2> hits;
    renderPair(*scene, out.cameras[0], out.cameras[1], ro, out.pair, hits[0], hits[1]);
    out.renderSeconds = secondsSince(t);

    // Every ray that met the surface met it inside the exact box; those that met nothing pass
    // no leaf of the level set that is not wholly inside it.
    t = Clock::now();
    bool anyMiss = false;
    std::size_t outside = 0;
    for (int v = 0; v < 2; ++v)
        for (int y = 0; y < hits[v].height; ++y)
            for (int x = 0; x < hits[v].width; ++x) {
                if (!(hits[v].t[std::size_t(y) * std::size_t(hits[v].width) + std::size_t(x)] >= 0.0f)) {
                    anyMiss = true;
                    continue;
                }
                const Vec3d hit = hitPointMm(out.cameras[std::size_t(v)], hits[v], x, y);
                if (!exact.contains(hit)) ++outside;
            }
    if (anyMiss) {
        const std::unique_ptr<RayScene> leafBoxes = leafBoxScene(sdf, exact, out.cameras, ro, out.checkLeaves);
        if (leafBoxes) {
            RenderOptions plain = ro;
            plain.ost = false;
            for (int v = 0; v < 2; ++v) {
                HitImage boxHits;
                traceHits(*leafBoxes, out.cameras[std::size_t(v)], plain, boxHits);
                for (std::size_t i = 0; i < boxHits.t.size(); ++i)
                    if (!(hits[v].t[i] >= 0.0f) && boxHits.t[i] >= 0.0f) ++out.uncertainPixels;
            }
        }
    }
    out.checkSeconds = secondsSince(t);
    if (outside > 0 || out.uncertainPixels > 0) {
        out.reason = std::to_string(outside) + " rays meet the surface outside the exact box, " +
                     std::to_string(out.uncertainPixels) + " that meet nothing here pass the level set outside it";
        return out;
    }
    out.certified = true;
    return out;
}

} // namespace flyover
