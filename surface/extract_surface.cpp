// GCC 12 reports -Wmaybe-uninitialized inside OpenMesh's PropertyT<Vec3f>::push_back (OpenMesh's
// VectorT default constructor leaves its components uninitialised on purpose) even though the
// code lives in system headers. Pragma scope is by source location, so ignoring it around the
// includes silences only the third-party code, not this file.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "surface/extract_surface.h"

#include "surface/mesh_build.h"
#include "surface/mesh_checks.h"
#include "volume/error.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>
#pragma GCC diagnostic pop

namespace flyover {

namespace {

using Tri = TriangleSoup::value_type;

} // namespace

/// Named, not anonymous: LumenSideTest::Impl holds one.
namespace extract_surface_detail {

/// GridSampler<FloatGrid::ConstAccessor, BoxSampler>::wsSample, the same arithmetic (the
/// transform's worldToIndex, BoxSampler's floor and fraction, its trilinearInterpolation), but
/// the eight corners are read from their leaf when they share one (7^3 / 8^3 of the samples)
/// instead of by eight tree look-ups: the same values, bit for bit.
///
/// worldToIndex is inlined for the maps OpenVDB gives axis-aligned grids (ScaleTranslateMap
/// and its UniformScaleTranslateMap, whose applyInverseMap is ScaleTranslateMap's final one:
/// (x - translation) * inverse scale per axis, the same operations here); any other map goes
/// through the transform's virtual call.
class Sampler {
public:
    using LeafT = openvdb::FloatTree::LeafNodeType;

    Sampler(const openvdb::FloatGrid::ConstAccessor& accessor, const openvdb::math::Transform& transform)
        : mAccessor(&accessor), mTransform(&transform)
    {
        if (const auto* map = dynamic_cast<const openvdb::math::ScaleTranslateMap*>(transform.baseMap().get())) {
            mScaleTranslate = true;
            mTranslation = map->getTranslation();
            mInverseScale = map->getInvScale();
        }
    }

    openvdb::Vec3d worldToIndex(const openvdb::Vec3d& world) const
    {
        if (!mScaleTranslate) return mTransform->worldToIndex(world);
        return openvdb::Vec3d((world.x() - mTranslation.x()) * mInverseScale.x(),
                              (world.y() - mTranslation.y()) * mInverseScale.y(),
                              (world.z() - mTranslation.z()) * mInverseScale.z());
    }

    float wsSample(const openvdb::Vec3d& world) const { return isSample(worldToIndex(world)); }

    /// The central-difference gradient of classifyTriangle: per axis a,
    /// (wsSample(c + h e_a) - wsSample(c - h e_a)) / 2h. Each corner is read from its leaf's
    /// value array; the few leaves the six samples touch are each looked up once.
    openvdb::Vec3d gradient(const openvdb::Vec3d& c, double h) const
    {
        LeafValues leaves(*mAccessor);
        float sample[6];
        for (int s = 0; s < 6; ++s) {
            openvdb::Vec3d e(0.0);
            e[s / 2] = h;
            const openvdb::Vec3d index = worldToIndex((s & 1) ? c - e : c + e);
            const openvdb::Vec3i floor = openvdb::tools::local_util::floorVec3(index);
            const openvdb::Vec3R uvw = index - floor;
            const openvdb::Coord ijk(floor);
            float data[2][2][2];
            if ((ijk.x() & 7) != 7 && (ijk.y() & 7) != 7 && (ijk.z() & 7) != 7) {
                if (const float* values = leaves.of(ijk))
                    readLeafCorners(values, LeafT::coordToOffset(ijk), data);
                else
                    cornersAcrossLeaves(ijk, data);
            } else {
                for (int i = 0; i < 2; ++i)
                    for (int j = 0; j < 2; ++j)
                        for (int k = 0; k < 2; ++k) {
                            const openvdb::Coord corner = ijk.offsetBy(i, j, k);
                            const float* values = leaves.of(corner);
                            data[i][j][k] =
                                values ? values[LeafT::coordToOffset(corner)] : mAccessor->getValue(corner);
                        }
            }
            sample[s] = openvdb::tools::BoxSampler::trilinearInterpolation(data, uvw);
        }
        openvdb::Vec3d grad;
        for (int a = 0; a < 3; ++a)
            grad[a] = (double(sample[2 * a]) - double(sample[2 * a + 1])) / (2.0 * h);
        return grad;
    }

private:
    /// The value arrays of the leaves looked up so far (by origin; at most eight kept): null
    /// where there is no leaf or it has no values (such a corner is read through the
    /// accessor: the tile's or background's value, or the empty leaf's own, as before).
    class LeafValues {
    public:
        explicit LeafValues(const openvdb::FloatGrid::ConstAccessor& accessor) : mAccessor(accessor) {}
        const float* of(const openvdb::Coord& ijk)
        {
            const openvdb::Coord origin(ijk.x() & ~7, ijk.y() & ~7, ijk.z() & ~7);
            for (int i = 0; i < mCount; ++i)
                if (mOrigin[i] == origin) return mValues[i];
            const LeafT* leaf = mAccessor.probeConstLeaf(ijk);
            const float* values = leaf && !leaf->buffer().empty() ? leaf->buffer().data() : nullptr;
            const int slot = mCount < 8 ? mCount++ : 7;
            mOrigin[slot] = origin;
            mValues[slot] = values;
            return values;
        }

    private:
        const openvdb::FloatGrid::ConstAccessor& mAccessor;
        openvdb::Coord mOrigin[8];
        const float* mValues[8];
        int mCount = 0;
    };

    /// Offsets within a leaf: x * 64 + y * 8 + z (LeafNode::coordToOffset).
    static void readLeafCorners(const float* v, openvdb::Index o, float (&data)[2][2][2])
    {
        data[0][0][0] = v[o];
        data[0][0][1] = v[o + 1];
        data[0][1][0] = v[o + 8];
        data[0][1][1] = v[o + 9];
        data[1][0][0] = v[o + 64];
        data[1][0][1] = v[o + 65];
        data[1][1][0] = v[o + 72];
        data[1][1][1] = v[o + 73];
    }

    float isSample(const openvdb::Vec3d& index) const
    {
        const openvdb::Vec3i floor = openvdb::tools::local_util::floorVec3(index);
        const openvdb::Vec3R uvw = index - floor;
        const openvdb::Coord ijk(floor);
        float data[2][2][2];
        const LeafT* leaf = nullptr;
        if ((ijk.x() & 7) != 7 && (ijk.y() & 7) != 7 && (ijk.z() & 7) != 7) leaf = mAccessor->probeConstLeaf(ijk);
        if (leaf && !leaf->buffer().empty()) {
            readLeafCorners(leaf->buffer().data(), LeafT::coordToOffset(ijk), data);
        } else {
            cornersAcrossLeaves(ijk, data);
        }
        return openvdb::tools::BoxSampler::trilinearInterpolation(data, uvw);
    }

    /// BoxSampler::probeValues' values (each corner's value, active or not) when the corners
    /// lie in several leaves or in none: each leaf they touch is looked up once (the accessor's
    /// one-leaf cache would otherwise alternate between them, corner after corner), a corner
    /// outside every leaf (a tile, the background) is read through the accessor.
    void cornersAcrossLeaves(const openvdb::Coord& ijk, float (&data)[2][2][2]) const
    {
        const int cross[3] = {(ijk.x() & 7) == 7, (ijk.y() & 7) == 7, (ijk.z() & 7) == 7};
        // Each leaf's values; null where there is no leaf or it has no values (a corner there is
        // read through the accessor: the tile's or the background's value, or the empty
        // leaf's own, as before).
        const float* values[2][2][2] = {};
        for (int i = 0; i <= cross[0]; ++i)
            for (int j = 0; j <= cross[1]; ++j)
                for (int k = 0; k <= cross[2]; ++k) {
                    const LeafT* leaf = mAccessor->probeConstLeaf(ijk.offsetBy(i, j, k));
                    values[i][j][k] = leaf && !leaf->buffer().empty() ? leaf->buffer().data() : nullptr;
                }
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 2; ++j)
                for (int k = 0; k < 2; ++k) {
                    const openvdb::Coord c = ijk.offsetBy(i, j, k);
                    const float* v = values[i & cross[0]][j & cross[1]][k & cross[2]];
                    data[i][j][k] = v ? v[LeafT::coordToOffset(c)] : mAccessor->getValue(c);
                }
    }

    const openvdb::FloatGrid::ConstAccessor* mAccessor;
    const openvdb::math::Transform* mTransform;
    bool mScaleTranslate = false;
    openvdb::Vec3d mTranslation, mInverseScale;
};

} // namespace extract_surface_detail

namespace {

using extract_surface_detail::Sampler;

/// Which way triangle p points relative to the level set: its normal (p1 - p0) x (p2 - p0)
/// against -grad(sdf) at its centroid. The gradient is a central difference over one voxel
/// (h, the smallest voxel edge) of trilinear world-space samples: valid for any affine (even
/// rotated or anisotropic) grid transform, unlike an index-space stencil.
FaceSide classifyTriangle(const Sampler& sampler, double h, const std::array<openvdb::Vec3d, 3>& p,
                          openvdb::Vec3d* gradientOut = nullptr)
{
    const openvdb::Vec3d n = (p[1] - p[0]).cross(p[2] - p[0]);
    const double longest2 =
        std::max({(p[1] - p[0]).lengthSqr(), (p[2] - p[1]).lengthSqr(), (p[0] - p[2]).lengthSqr()});
    if (isDegenerateTriangle(n.length(), longest2)) return FaceSide::Degenerate;
    const openvdb::Vec3d c = (p[0] + p[1] + p[2]) / 3.0;
    const openvdb::Vec3d grad = sampler.gradient(c, h);
    if (gradientOut) *gradientOut = grad;
    if (!(grad.lengthSqr() > 0.0)) return FaceSide::NoGradient;
    return -n.dot(grad) > 0.0 ? FaceSide::Inward : FaceSide::Outward;
}

double gradientStepMm(const openvdb::FloatGrid& sdf)
{
    const openvdb::Vec3d voxel = sdf.voxelSize();
    return std::min({voxel[0], voxel[1], voxel[2]});
}

/// Counts per class, plus the indices of the faces that are not inward (rare: a plain
/// vector per task, joined in index order).
struct OrientationTally {
    FaceOrientation count;
    std::vector<std::size_t> notInward;
    std::vector<FaceSide> notInwardSide;  ///< the class of each of notInward
};

/// Classifies every `stride`-th face (see classifyTriangle). `corners(i, p)` writes the
/// corners of face i (world mm) into p.
template<typename CornersFn>
OrientationTally tallyOrientation(const openvdb::FloatGrid& sdf, std::size_t faceCount, std::size_t stride,
                                  const CornersFn& corners)
{
    const double h = gradientStepMm(sdf);
    const std::size_t samples = (faceCount + stride - 1) / stride;
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, samples, 1024), OrientationTally{},
        [&](const tbb::blocked_range<std::size_t>& range, OrientationTally acc) {
            openvdb::FloatGrid::ConstAccessor accessor = sdf.getConstAccessor();
            const Sampler sampler(accessor, sdf.transform());
            std::array<openvdb::Vec3d, 3> p;
            for (std::size_t s = range.begin(); s != range.end(); ++s) {
                corners(s * stride, p);
                const FaceSide side = classifyTriangle(sampler, h, p);
                acc.count.add(side);
                if (side != FaceSide::Inward) {
                    acc.notInward.push_back(s * stride);
                    acc.notInwardSide.push_back(side);
                }
            }
            return acc;
        },
        [](OrientationTally a, const OrientationTally& b) {
            a.count.inward += b.count.inward;
            a.count.outward += b.count.outward;
            a.count.degenerate += b.count.degenerate;
            a.count.noGradient += b.count.noGradient;
            // Joins are of adjacent ranges, left then right: the order stays ascending.
            a.notInward.insert(a.notInward.end(), b.notInward.begin(), b.notInward.end());
            a.notInwardSide.insert(a.notInwardSide.end(), b.notInwardSide.begin(), b.notInwardSide.end());
            return a;
        });
}

template<typename CornersFn>
FaceOrientation countInwardFaces(const openvdb::FloatGrid& sdf, std::size_t faceCount, std::size_t stride,
                                 const CornersFn& corners)
{
    return tallyOrientation(sdf, faceCount, stride, corners).count;
}

std::array<openvdb::Vec3d, 3> faceCorners(const TriMesh& mesh, TriMesh::FaceHandle f)
{
    std::array<openvdb::Vec3d, 3> p;
    int k = 0;
    for (const auto v : mesh.fv_range(f)) {
        const TriMesh::Point& q = mesh.point(v);
        p[std::size_t(k++)] = openvdb::Vec3d(q[0], q[1], q[2]);
    }
    return p;
}

OrientationTally tallyMeshOrientation(const TriMesh& mesh, const openvdb::FloatGrid& sdf)
{
    return tallyOrientation(sdf, mesh.n_faces(), 1, [&](std::size_t i, std::array<openvdb::Vec3d, 3>& p) {
        p = faceCorners(mesh, TriMesh::FaceHandle(int(i)));
    });
}

FaceOrientation countMeshOrientation(const TriMesh& mesh, const openvdb::FloatGrid& sdf)
{
    return tallyMeshOrientation(mesh, sdf).count;
}


/// Edge-connected components by depth-first search over face neighbours.
int64_t countComponents(const TriMesh& mesh)
{
    std::vector<char> seen(mesh.n_faces(), 0);
    std::vector<TriMesh::FaceHandle> stack;
    int64_t components = 0;
    for (const auto f : mesh.faces()) {
        if (seen[f.idx()]) continue;
        ++components;
        seen[f.idx()] = 1;
        stack.push_back(f);
        while (!stack.empty()) {
            const TriMesh::FaceHandle g = stack.back();
            stack.pop_back();
            for (auto ff = mesh.cff_iter(g); ff.is_valid(); ++ff) {
                if (!seen[ff->idx()]) {
                    seen[ff->idx()] = 1;
                    stack.push_back(*ff);
                }
            }
        }
    }
    return components;
}

/// The faces (not deleted) without a usable normal, in face order: parallel over the faces,
/// the parts joined left then right.
std::vector<TriMesh::FaceHandle> degenerateFaces(const TriMesh& mesh)
{
    using Faces = std::vector<TriMesh::FaceHandle>;
    const bool hasStatus = mesh.has_face_status();
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, mesh.n_faces(), 8192), Faces{},
        [&](const tbb::blocked_range<std::size_t>& range, Faces faces) {
            for (std::size_t i = range.begin(); i != range.end(); ++i) {
                const TriMesh::FaceHandle f{int(i)};
                if (!(hasStatus && mesh.status(f).deleted()) && isDegenerateFace(mesh, f)) faces.push_back(f);
            }
            return faces;
        },
        [](Faces a, const Faces& b) {
            a.insert(a.end(), b.begin(), b.end());
            return a;
        });
}

/// Removes faces without a usable normal, which volumeToMesh emits where two of its
/// vertices coincide (a needle) and which a smoother would turn into slivers of random
/// orientation. A needle loses its shortest edge by a collapse (the geometry moves by that
/// edge's length, about zero); a cap (a corner lying on the opposite edge) has its longest
/// edge flipped. Both keep the topology (is_collapse_ok, is_flip_ok) and the winding.
struct DegenerateRepair {
    int64_t operations = 0;    ///< collapses and flips
    int64_t removedFaces = 0;  ///< faces the collapses removed
};

DegenerateRepair repairDegenerateFaces(TriMesh& mesh)
{
    std::vector<TriMesh::FaceHandle> bad = degenerateFaces(mesh);
    if (bad.empty()) return {};
    const std::size_t facesBefore = mesh.n_faces();

    mesh.request_vertex_status();
    mesh.request_edge_status();
    mesh.request_face_status();
    DegenerateRepair repair;
    // A repair can leave a neighbour degenerate (a cap next to a needle): a few passes.
    for (int pass = 0; pass < 4 && !bad.empty(); ++pass) {
        for (const TriMesh::FaceHandle f : bad) {
            if (mesh.status(f).deleted() || !isDegenerateFace(mesh, f)) continue;
            TriMesh::HalfedgeHandle shortest, longest;
            double shortLen = std::numeric_limits<double>::max(), longLen = -1.0;
            for (const auto h : mesh.fh_range(f)) {
                const double len = mesh.calc_edge_length(h);
                if (len < shortLen) { shortLen = len; shortest = h; }
                if (len > longLen) { longLen = len; longest = h; }
            }
            if (shortLen <= 1e-3 * longLen) {
                if (mesh.is_collapse_ok(shortest)) {
                    mesh.collapse(shortest);
                    ++repair.operations;
                } else if (mesh.is_collapse_ok(mesh.opposite_halfedge_handle(shortest))) {
                    mesh.collapse(mesh.opposite_halfedge_handle(shortest));
                    ++repair.operations;
                }
            } else if (mesh.is_flip_ok(mesh.edge_handle(longest))) {
                mesh.flip(mesh.edge_handle(longest));
                ++repair.operations;
            }
        }
        bad = degenerateFaces(mesh);
    }
    mesh.garbage_collection();
    mesh.release_face_status();
    mesh.release_edge_status();
    mesh.release_vertex_status();
    repair.removedFaces = int64_t(facesBefore) - int64_t(mesh.n_faces());
    return repair;
}

template<typename T>
void releaseVector(std::vector<T>& v)
{
    std::vector<T>().swap(v);
}

} // namespace

/// Edge checks on the triangle soup, before OpenMesh refuses anything: the number of edges
/// with more than two triangles, and of edges two triangles traverse in the same direction.
std::pair<int64_t, int64_t> countSoupEdgeProblems(const TriangleSoup& tris)
{
    // Key: (min vertex, max vertex) in the high 63 bits, direction (a < b) in the lowest bit.
    std::vector<uint64_t> keys;
    keys.reserve(3 * tris.size());
    for (const Tri& t : tris)
        for (int k = 0; k < 3; ++k) {
            const uint64_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            keys.push_back((std::min(a, b) << 32 | std::max(a, b)) << 1 | uint64_t(a < b));
        }
    tbb::parallel_sort(keys.begin(), keys.end());
    int64_t nonManifold = 0, conflicts = 0;
    for (std::size_t i = 0; i < keys.size();) {
        std::size_t j = i;
        std::size_t forward = 0;
        while (j < keys.size() && (keys[j] >> 1) == (keys[i] >> 1)) forward += keys[j++] & 1u;
        const std::size_t uses = j - i;
        if (uses > 2) ++nonManifold;
        else if (uses == 2 && forward != 1) ++conflicts;
        i = j;
    }
    return {nonManifold, conflicts};
}

TriMesh extractSurface(const openvdb::FloatGrid& sdf, const MeshParams& params, MeshStats* stats,
                       Progress* progress, bool surfaceStats, std::shared_ptr<const TriangleSoup>* soup)
{
    if (!std::isfinite(params.isoValueMm)) {
        std::ostringstream msg;
        msg << "MeshParams.isoValueMm: expected a finite value, got " << params.isoValueMm;
        throw ParameterError(msg.str());
    }
    if (!(params.adaptivity >= 0.0 && params.adaptivity <= 1.0)) {
        std::ostringstream msg;
        msg << "MeshParams.adaptivity: expected a value in [0, 1], got " << params.adaptivity;
        throw ParameterError(msg.str());
    }

    reportProgress(progress, 0.0, "volumeToMesh");
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(sdf, points, triangles, quads, params.isoValueMm,
                                 params.adaptivity);

    if (points.empty() || (triangles.empty() && quads.empty())) {
        std::ostringstream msg;
        msg << "extractSurface: grid '" << sdf.getName() << "' (" << sdf.activeVoxelCount()
            << " active voxels) has no zero crossing at iso-value " << params.isoValueMm
            << " mm: the lumen level set is empty or has no surface";
        throw InputError(msg.str());
    }

    reportProgress(progress, 0.4, "split quads");
    // Quads are split along their shorter diagonal (better-shaped triangles); both halves keep
    // the quad's winding, so the orientation volumeToMesh chose is preserved.
    std::vector<Tri> tris;
    tris.reserve(triangles.size() + 2 * quads.size());
    for (const auto& t : triangles) tris.push_back({t[0], t[1], t[2]});
    releaseVector(triangles);
    for (const auto& q : quads) {
        const double d02 = (points[q[2]] - points[q[0]]).lengthSqr();
        const double d13 = (points[q[3]] - points[q[1]]).lengthSqr();
        if (d02 <= d13) {
            tris.push_back({q[0], q[1], q[2]});
            tris.push_back({q[0], q[2], q[3]});
        } else {
            tris.push_back({q[0], q[1], q[3]});
            tris.push_back({q[1], q[2], q[3]});
        }
    }
    releaseVector(quads);

    // Orientation check: volumeToMesh is documented (toolchain.md) to wind faces towards the
    // negative side. We measure it on a strided sample instead of trusting it, and flip every
    // face only if the majority points the other way. The final fraction over all faces is
    // measured again on the finished mesh (stats.inwardFraction).
    reportProgress(progress, 0.5, "orientation check");
    const std::size_t stride = std::max<std::size_t>(1, tris.size() / 20000);
    const FaceOrientation sample =
        countInwardFaces(sdf, tris.size(), stride, [&](std::size_t i, std::array<openvdb::Vec3d, 3>& p) {
            for (int k = 0; k < 3; ++k) p[k] = openvdb::Vec3d(points[tris[i][k]]);
        });
    if (sample.outward > sample.inward) {
        for (auto& t : tris) std::swap(t[1], t[2]);
    }
    // Vertex indices fit in 32 bits (volumeToMesh uses Vec3I/Vec4I).
    // Counted here, or by the caller from the soup handed back.
    const auto [nonManifoldEdges, orientationConflicts] =
        stats && !soup ? countSoupEdgeProblems(tris) : std::pair<int64_t, int64_t>(0, 0);

    reportProgress(progress, 0.6, "build mesh");
    // Only vertices referenced by a face enter the mesh (adaptive meshing can leave unused
    // points), so vertex counts and the Euler characteristic are those of the surface.
    constexpr int UNUSED = -1;
    std::vector<int> vertexIndex(points.size(), UNUSED);
    int nextVertex = 0;
    for (const auto& t : tris)
        for (const uint32_t v : t)
            if (vertexIndex[v] == UNUSED) vertexIndex[v] = nextVertex++;

    TriMesh mesh;
    // All vertices at once (resize, then set_point) rather than add_vertex one by one.
    mesh.resize(std::size_t(nextVertex), 0, 0);
    for (std::size_t i = 0; i < points.size(); ++i) {
        if (vertexIndex[i] == UNUSED) continue;
        const openvdb::Vec3s& p = points[i];
        mesh.set_point(TriMesh::VertexHandle(vertexIndex[i]), TriMesh::Point(p.x(), p.y(), p.z()));
    }
    releaseVector(points);

    // The faces as add_face would add them one by one (the same refusals, handles and order),
    // built on flat arrays: ~0.05 instead of ~0.13 CPU s of add_face's loop on the full phantom.
    std::vector<std::array<int, 3>> faces(tris.size());
    for (std::size_t i = 0; i < tris.size(); ++i)
        faces[i] = {vertexIndex[tris[i][0]], vertexIndex[tris[i][1]], vertexIndex[tris[i][2]]};
    const int64_t dropped = addFacesLikeOpenMesh(mesh, faces);
    releaseVector(faces);
    if (soup) *soup = std::make_shared<const TriangleSoup>(std::move(tris));
    releaseVector(tris);
    releaseVector(vertexIndex);

    reportProgress(progress, 0.7, "repair degenerate faces");
    const DegenerateRepair repaired = repairDegenerateFaces(mesh);

    if (stats) {
        reportProgress(progress, 0.8, "mesh statistics");
        MeshStats s;
        s.vertices = int64_t(mesh.n_vertices());
        s.faces = int64_t(mesh.n_faces());
        for (const auto e : mesh.edges())
            if (e.is_boundary()) ++s.boundaryEdges;
        s.droppedFaces = dropped;
        s.degenerateRepairs = repaired.operations;
        s.removedDegenerateFaces = repaired.removedFaces;
        s.nonManifoldEdges = nonManifoldEdges;
        s.orientationConflicts = orientationConflicts;
        if (surfaceStats) {
            s.components = countComponents(mesh);
            s.areaMm2 = surfaceAreaMm2(mesh);
            s.enclosedVolumeMm3 = enclosedVolumeInward(mesh);
            const FaceOrientation orientation = countMeshOrientation(mesh, sdf);
            s.degenerateFaces = orientation.degenerate;
            s.inwardFraction = orientation.inwardFraction();
        }
        *stats = s;
    }
    reportProgress(progress, 1.0, "mesh done");
    return mesh;
}

FaceOrientation checkFaceOrientation(const TriMesh& mesh, const openvdb::FloatGrid& sdf,
                                     std::vector<TriMesh::FaceHandle>* notInward,
                                     std::vector<FaceSide>* notInwardSides)
{
    OrientationTally tally = tallyMeshOrientation(mesh, sdf);
    if (notInward) {
        notInward->clear();
        for (const std::size_t i : tally.notInward) notInward->push_back(TriMesh::FaceHandle(int(i)));
    }
    if (notInwardSides) *notInwardSides = std::move(tally.notInwardSide);
    return tally.count;
}

struct LumenSideTest::Impl {
    explicit Impl(const openvdb::FloatGrid& grid)
        : accessor(grid.getConstAccessor()), sampler(accessor, grid.transform()), h(gradientStepMm(grid))
    {
    }
    openvdb::FloatGrid::ConstAccessor accessor;
    Sampler sampler;
    double h;
};

LumenSideTest::LumenSideTest(const openvdb::FloatGrid& sdf) : mImpl(std::make_unique<Impl>(sdf)) {}
LumenSideTest::~LumenSideTest() = default;

bool LumenSideTest::isInward(const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b, const OpenMesh::Vec3d& c) const
{
    return classify(a, b, c) == FaceSide::Inward;
}

FaceSide LumenSideTest::classify(const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b, const OpenMesh::Vec3d& c,
                                 OpenMesh::Vec3d* gradient) const
{
    const std::array<openvdb::Vec3d, 3> p{openvdb::Vec3d(a[0], a[1], a[2]), openvdb::Vec3d(b[0], b[1], b[2]),
                                          openvdb::Vec3d(c[0], c[1], c[2])};
    openvdb::Vec3d g(0.0);
    const FaceSide side = classifyTriangle(mImpl->sampler, mImpl->h, p, &g);
    if (gradient) *gradient = OpenMesh::Vec3d(g[0], g[1], g[2]);
    return side;
}

float LumenSideTest::valueAt(const OpenMesh::Vec3d& world) const
{
    return mImpl->sampler.wsSample(openvdb::Vec3d(world[0], world[1], world[2]));
}

double inwardFaceFraction(const TriMesh& mesh, const openvdb::FloatGrid& sdf)
{
    return countMeshOrientation(mesh, sdf).inwardFraction();
}

double enclosedVolumeInward(const TriMesh& mesh)
{
    if (mesh.n_faces() == 0) return 0.0;
    // Tetrahedra against a reference point near the mesh: the sum is independent of that point
    // for a closed surface, and a nearby one keeps the float cancellation small.
    OpenMesh::Vec3d lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (const auto v : mesh.vertices()) {
        const OpenMesh::Vec3d p = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v));
        lo.minimize(p);
        hi.maximize(p);
    }
    const OpenMesh::Vec3d ref = 0.5 * (lo + hi);
    double sum = 0.0;
    for (const auto f : mesh.faces()) {
        std::array<OpenMesh::Vec3d, 3> p;
        int k = 0;
        for (const auto v : mesh.fv_range(f))
            p[k++] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v)) - ref;
        sum += OpenMesh::dot(p[0], OpenMesh::cross(p[1], p[2]));
    }
    // Outward-oriented closed surfaces give +V with this sum; ours point inward.
    return -sum / 6.0;
}

double surfaceAreaMm2(const TriMesh& mesh)
{
    double area = 0.0;
    for (const auto f : mesh.faces()) {
        std::array<OpenMesh::Vec3d, 3> p;
        int k = 0;
        for (const auto v : mesh.fv_range(f))
            p[k++] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v));
        area += 0.5 * OpenMesh::cross(p[1] - p[0], p[2] - p[0]).norm();
    }
    return area;
}

} // namespace flyover
