// GCC 12 reports -Wmaybe-uninitialized inside OpenMesh's PropertyT<Vec3f>::push_back (OpenMesh's
// VectorT default constructor leaves its components uninitialised on purpose) even though the
// code lives in system headers. Pragma scope is by source location, so ignoring it around the
// includes silences only the third-party code, not this file.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "surface/extract_surface.h"

#include "volume/error.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <vector>
#pragma GCC diagnostic pop

namespace flyover {

namespace {

using Tri = std::array<uint32_t, 3>;

/// Orientation of faces relative to the SDF, counted by countInwardFaces.
struct OrientationCount {
    std::size_t inward = 0;      ///< normal . -grad > 0
    std::size_t outward = 0;     ///< normal . -grad < 0
    std::size_t degenerate = 0;  ///< zero normal: no orientation at all
    std::size_t noGradient = 0;  ///< zero gradient (outside the band): orientation unknown
};

/// Classifies every `stride`-th face by whether its normal (v1 - v0) x (v2 - v0) agrees with
/// -grad(sdf) at its centroid. `corners(i, p)` writes the corners of face i (world mm) into p.
template<typename CornersFn>
OrientationCount countInwardFaces(const openvdb::FloatGrid& sdf, std::size_t faceCount,
                                  std::size_t stride, const CornersFn& corners)
{
    using Sampler =
        openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler>;
    // Central differences over one voxel, sampled trilinearly in world space: valid for any
    // affine (even rotated or anisotropic) grid transform, unlike an index-space stencil.
    const openvdb::Vec3d voxel = sdf.voxelSize();
    const double h = std::min({voxel[0], voxel[1], voxel[2]});
    const std::size_t samples = (faceCount + stride - 1) / stride;

    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, samples, 1024), OrientationCount{},
        [&](const tbb::blocked_range<std::size_t>& range, OrientationCount acc) {
            openvdb::FloatGrid::ConstAccessor accessor = sdf.getConstAccessor();
            Sampler sampler(accessor, sdf.transform());
            std::array<openvdb::Vec3d, 3> p;
            for (std::size_t s = range.begin(); s != range.end(); ++s) {
                corners(s * stride, p);
                const openvdb::Vec3d n = (p[1] - p[0]).cross(p[2] - p[0]);
                const openvdb::Vec3d c = (p[0] + p[1] + p[2]) / 3.0;
                openvdb::Vec3d grad;
                for (int a = 0; a < 3; ++a) {
                    openvdb::Vec3d e(0.0);
                    e[a] = h;
                    grad[a] = (double(sampler.wsSample(c + e)) - double(sampler.wsSample(c - e))) /
                              (2.0 * h);
                }
                const double d = -n.dot(grad);
                if (!(n.lengthSqr() > 0.0)) ++acc.degenerate;
                else if (!(grad.lengthSqr() > 0.0)) ++acc.noGradient;
                else if (d > 0.0) ++acc.inward;
                else ++acc.outward;
            }
            return acc;
        },
        [](OrientationCount a, const OrientationCount& b) {
            a.inward += b.inward;
            a.outward += b.outward;
            a.degenerate += b.degenerate;
            a.noGradient += b.noGradient;
            return a;
        });
}

OrientationCount countMeshOrientation(const TriMesh& mesh, const openvdb::FloatGrid& sdf)
{
    return countInwardFaces(sdf, mesh.n_faces(), 1, [&](std::size_t i, std::array<openvdb::Vec3d, 3>& p) {
        int k = 0;
        for (const auto v : mesh.fv_range(TriMesh::FaceHandle(int(i)))) {
            const TriMesh::Point& q = mesh.point(v);
            p[std::size_t(k++)] = openvdb::Vec3d(q[0], q[1], q[2]);
        }
    });
}

/// Zero-area faces have no orientation and are left out; faces without a gradient count as
/// not inward (a mesh that does not match its grid must not look well oriented).
double inwardFraction(const OrientationCount& count, std::size_t faces)
{
    const std::size_t oriented = faces - count.degenerate;
    return oriented > 0 ? double(count.inward) / double(oriented) : 0.0;
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

/// OpenMesh prints one line per refused face on its error stream; we count them instead.
/// Note: omerr() is process-wide, so this guard assumes no other thread is reporting
/// OpenMesh errors at the same time (losing such a message is the only consequence).
class OpenMeshErrorsMuted {
public:
    OpenMeshErrorsMuted() : mWasEnabled(omerr().is_enabled()) { omerr().disable(); }
    ~OpenMeshErrorsMuted()
    {
        if (mWasEnabled) omerr().enable();
    }
    OpenMeshErrorsMuted(const OpenMeshErrorsMuted&) = delete;
    OpenMeshErrorsMuted& operator=(const OpenMeshErrorsMuted&) = delete;

private:
    bool mWasEnabled;
};

template<typename T>
void releaseVector(std::vector<T>& v)
{
    std::vector<T>().swap(v);
}

} // namespace

TriMesh extractSurface(const openvdb::FloatGrid& sdf, const MeshParams& params, MeshStats* stats,
                       Progress* progress)
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
    const OrientationCount sample =
        countInwardFaces(sdf, tris.size(), stride, [&](std::size_t i, std::array<openvdb::Vec3d, 3>& p) {
            for (int k = 0; k < 3; ++k) p[k] = openvdb::Vec3d(points[tris[i][k]]);
        });
    if (sample.outward > sample.inward) {
        for (auto& t : tris) std::swap(t[1], t[2]);
    }

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
    mesh.reserve(std::size_t(nextVertex), tris.size() * 3 / 2 + 16, tris.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        if (vertexIndex[i] == UNUSED) continue;
        const openvdb::Vec3s& p = points[i];
        mesh.set_point(TriMesh::VertexHandle(vertexIndex[i]), TriMesh::Point(p.x(), p.y(), p.z()));
    }
    releaseVector(points);

    int64_t dropped = 0;
    {
        const OpenMeshErrorsMuted muted;
        for (const auto& t : tris) {
            const TriMesh::VertexHandle a(vertexIndex[t[0]]), b(vertexIndex[t[1]]),
                c(vertexIndex[t[2]]);
            // volumeToMesh can emit a collapsed triangle with a repeated vertex; OpenMesh
            // would refuse it as well, count it the same way.
            if (a == b || b == c || a == c || !mesh.add_face(a, b, c).is_valid()) ++dropped;
        }
    }
    releaseVector(tris);
    releaseVector(vertexIndex);

    if (stats) {
        reportProgress(progress, 0.8, "mesh statistics");
        MeshStats s;
        s.vertices = int64_t(mesh.n_vertices());
        s.faces = int64_t(mesh.n_faces());
        s.components = countComponents(mesh);
        for (const auto e : mesh.edges())
            if (e.is_boundary()) ++s.boundaryEdges;
        s.droppedFaces = dropped;
        s.areaMm2 = surfaceAreaMm2(mesh);
        s.enclosedVolumeMm3 = enclosedVolumeInward(mesh);
        const OrientationCount orientation = countMeshOrientation(mesh, sdf);
        s.degenerateFaces = int64_t(orientation.degenerate);
        s.inwardFraction = inwardFraction(orientation, mesh.n_faces());
        *stats = s;
    }
    reportProgress(progress, 1.0, "mesh done");
    return mesh;
}

double inwardFaceFraction(const TriMesh& mesh, const openvdb::FloatGrid& sdf)
{
    return inwardFraction(countMeshOrientation(mesh, sdf), mesh.n_faces());
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
