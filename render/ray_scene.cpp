#include "render/ray_scene.h"

#include "render/ray_scene_impl.h"
#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace flyover {

namespace {

const char* errorName(RTCError code)
{
    switch (code) {
    case RTC_ERROR_NONE: return "RTC_ERROR_NONE";
    case RTC_ERROR_UNKNOWN: return "RTC_ERROR_UNKNOWN";
    case RTC_ERROR_INVALID_ARGUMENT: return "RTC_ERROR_INVALID_ARGUMENT";
    case RTC_ERROR_INVALID_OPERATION: return "RTC_ERROR_INVALID_OPERATION";
    case RTC_ERROR_OUT_OF_MEMORY: return "RTC_ERROR_OUT_OF_MEMORY";
    case RTC_ERROR_UNSUPPORTED_CPU: return "RTC_ERROR_UNSUPPORTED_CPU";
    case RTC_ERROR_CANCELLED: return "RTC_ERROR_CANCELLED";
    }
    return "unknown Embree error";
}

void recordEmbreeError(void* userPtr, RTCError code, const char* message)
{
    auto* state = static_cast<EmbreeErrorState*>(userPtr);
    const std::lock_guard<std::mutex> lock(state->mutex);
    if (state->code == RTC_ERROR_NONE) {
        state->code = code;
        state->message = message ? message : "";
    }
}

} // namespace

namespace {

/// OST's test: candidate i of a filter call hits a back face (the ray leaves its front side).
bool backFace(const RTCFilterFunctionNArguments* args, unsigned int i)
{
    const unsigned int n = args->N;
    const float d = RTCRayN_dir_x(args->ray, n, i) * RTCHitN_Ng_x(args->hit, n, i) +
                    RTCRayN_dir_y(args->ray, n, i) * RTCHitN_Ng_y(args->hit, n, i) +
                    RTCRayN_dir_z(args->ray, n, i) * RTCHitN_Ng_z(args->hit, n, i);
    return d > 0.0f;
}

} // namespace

void ostFilter(const RTCFilterFunctionNArguments* args)
{
    for (unsigned int i = 0; i < args->N; ++i)
        if (args->valid[i] == -1 && backFace(args, i)) args->valid[i] = 0;
}

void loopOstFilter(const RTCFilterFunctionNArguments* args)
{
    auto* loop = reinterpret_cast<LoopContext*>(args->context);
    int* valid = args->valid;
    RTCRayN* ray = args->ray;
    RTCHitN* hit = args->hit;
    const unsigned int n = args->N;
    for (unsigned int i = 0; i < n; ++i) {
        if (valid[i] != -1) continue;
        if (backFace(args, i)) {
            valid[i] = 0;
            continue;
        }
        const float arc = loop->ownerArc[RTCHitN_primID(hit, n, i)];
        if (arc < loop->arcLo || arc > loop->arcHi) {  // NaN: no owner, kept
            valid[i] = 0;
            float& passed = loop->passedT[RTCRayN_id(ray, n, i) & 15u];
            passed = std::min(passed, RTCRayN_tfar(ray, n, i));  // the candidate hit's distance
        }
    }
}

void RayScene::Impl::throwIfError(const char* what)
{
    RTCError code = RTC_ERROR_NONE;
    std::string message;
    {
        const std::lock_guard<std::mutex> lock(errors.mutex);
        std::swap(code, errors.code);
        std::swap(message, errors.message);
    }
    // The callback may not have fired (e.g. before it was installed): ask the device too.
    if (code == RTC_ERROR_NONE) code = rtcGetDeviceError(device);
    if (code != RTC_ERROR_NONE) {
        std::ostringstream msg;
        msg << "Embree: " << what << " failed: " << errorName(code);
        if (!message.empty()) msg << ": " << message;
        throw std::runtime_error(msg.str());
    }
}

RayScene::Impl::~Impl()
{
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
}

namespace {

std::vector<float> meshVertices(const TriMesh& mesh)
{
    std::vector<float> xyz(3 * mesh.n_vertices());
    const TriMesh::Point* points = mesh.points();
    for (std::size_t i = 0; i < mesh.n_vertices(); ++i)
        for (int k = 0; k < 3; ++k) xyz[3 * i + std::size_t(k)] = points[i][k];
    return xyz;
}

/// Triangle vertex indices in the order of the mesh's face-vertex circulator (which starts at
/// the to-vertex of the face's halfedge), three per face.
std::vector<uint32_t> meshTriangles(const TriMesh& mesh)
{
    if (mesh.n_faces() > std::size_t(std::numeric_limits<uint32_t>::max() / 3) ||
        mesh.n_vertices() >= std::size_t(std::numeric_limits<uint32_t>::max()))
        throw InputError("RayScene: mesh too large for 32-bit Embree indices");
    std::vector<uint32_t> tris(3 * mesh.n_faces());
    const bool hasStatus = mesh.has_face_status();
    std::atomic<int> problem{0};  // 1: deleted face, 2: not a triangle
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.n_faces(), 4096), [&](const auto& range) {
        for (std::size_t f = range.begin(); f != range.end(); ++f) {
            const TriMesh::FaceHandle fh{int(f)};
            if (hasStatus && mesh.status(fh).deleted()) {
                problem = 1;
                return;
            }
            const auto h0 = mesh.halfedge_handle(fh);
            const auto h1 = mesh.next_halfedge_handle(h0);
            const auto h2 = mesh.next_halfedge_handle(h1);
            if (mesh.next_halfedge_handle(h2) != h0) {
                problem = 2;
                return;
            }
            tris[3 * f] = uint32_t(mesh.to_vertex_handle(h0).idx());
            tris[3 * f + 1] = uint32_t(mesh.to_vertex_handle(h1).idx());
            tris[3 * f + 2] = uint32_t(mesh.to_vertex_handle(h2).idx());
        }
    });
    if (problem == 1) throw InputError("RayScene: mesh has deleted faces; call garbage_collection() first");
    if (problem == 2) throw InputError("RayScene: mesh face that is not a triangle");
    return tris;
}

/// Throws InputError unless there are three normal coordinates per vertex.
void checkNormals(const std::vector<float>& vertexNormalsXyz, const std::vector<float>& verticesXyz)
{
    if (vertexNormalsXyz.size() != verticesXyz.size()) {
        std::ostringstream msg;
        msg << "RayScene: " << vertexNormalsXyz.size() << " vertex normal coordinates for " << verticesXyz.size()
            << " vertex coordinates";
        throw InputError(msg.str());
    }
}

/// Vertex normals: sum of the unnormalised face normals (twice the face area times the unit
/// normal) of the incident faces, then normalised; the orientation is the faces' own. Face
/// normals in parallel; the scatter to vertices in order (deterministic sums). Arrays checked.
std::vector<float> normalsOf(const std::vector<float>& xyz, const std::vector<uint32_t>& indices)
{
    using Vertex = RayScene::Impl::Vertex;
    const std::size_t nv = xyz.size() / 3;
    const auto triangles = uint32_t(indices.size() / 3);
    auto at = [&](uint32_t i) {
        const float* p = &xyz[3 * std::size_t(i)];
        return Vertex{p[0], p[1], p[2]};
    };
    std::vector<Vertex> faceNormals(triangles);
    tbb::parallel_for(tbb::blocked_range<uint32_t>(0, triangles, 8192), [&](const auto& range) {
        for (uint32_t f = range.begin(); f != range.end(); ++f) {
            const uint32_t* t = &indices[3 * std::size_t(f)];
            const Vertex a = at(t[0]), b = at(t[1]), c = at(t[2]);
            const float ux = b.x - a.x, uy = b.y - a.y, uz = b.z - a.z;
            const float vx = c.x - a.x, vy = c.y - a.y, vz = c.z - a.z;
            faceNormals[f] = {uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx};
        }
    });
    std::vector<float> normals(3 * nv, 0.f);
    for (uint32_t f = 0; f < triangles; ++f) {
        const Vertex& n = faceNormals[f];
        for (int k = 0; k < 3; ++k) {
            float* acc = &normals[3 * std::size_t(indices[3 * std::size_t(f) + std::size_t(k)])];
            acc[0] += n.x;
            acc[1] += n.y;
            acc[2] += n.z;
        }
    }
    for (std::size_t i = 0; i < nv; ++i) {
        float* n = &normals[3 * i];
        const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (len > 0.f) {
            n[0] /= len;
            n[1] /= len;
            n[2] /= len;
        } else {
            n[0] = n[1] = n[2] = 0.f;
        }
    }
    return normals;
}

} // namespace

void checkTriangleArrays(const std::vector<float>& verticesXyz, const std::vector<uint32_t>& triangleIndices,
                         const std::string& where)
{
    if (verticesXyz.size() % 3 != 0 || triangleIndices.size() % 3 != 0)
        throw InputError(where + ": vertex coordinates and triangle indices must come in threes");
    const std::size_t nv = verticesXyz.size() / 3;
    if (triangleIndices.size() / 3 > std::size_t(std::numeric_limits<uint32_t>::max() / 3) ||
        nv >= std::size_t(std::numeric_limits<uint32_t>::max()))
        throw InputError(where + ": mesh too large for 32-bit Embree indices");
    for (const uint32_t i : triangleIndices)
        if (i >= nv) {
            std::ostringstream msg;
            msg << where << ": triangle vertex index " << i << " out of range (" << nv << " vertices)";
            throw InputError(msg.str());
        }
}

void triMeshArrays(const TriMesh& mesh, std::vector<float>& verticesXyz, std::vector<uint32_t>& triangleIndices)
{
    triangleIndices = meshTriangles(mesh);
    verticesXyz = meshVertices(mesh);
}

std::vector<float> smoothVertexNormals(const std::vector<float>& verticesXyz,
                                       const std::vector<uint32_t>& triangleIndices)
{
    checkTriangleArrays(verticesXyz, triangleIndices, "RayScene");
    const DenormalsFlushed flushed;  // as in the scene's constructor: the same bits
    return normalsOf(verticesXyz, triangleIndices);
}

std::unique_ptr<RayScene> sceneOfTriangles(const std::vector<float>& verticesXyz,
                                           const std::vector<float>& vertexNormalsXyz,
                                           const std::vector<uint32_t>& triangleIndices, const SceneOptions& options)
{
    checkTriangleArrays(verticesXyz, triangleIndices, "RayScene");
    checkNormals(vertexNormalsXyz, verticesXyz);
    constexpr uint32_t UNUSED = std::numeric_limits<uint32_t>::max();
    std::vector<uint32_t> newIndex(verticesXyz.size() / 3, UNUSED), indices(triangleIndices.size());
    std::vector<float> xyz, normals;
    for (std::size_t k = 0; k < triangleIndices.size(); ++k) {
        const uint32_t old = triangleIndices[k];
        if (newIndex[old] == UNUSED) {
            newIndex[old] = uint32_t(xyz.size() / 3);
            xyz.insert(xyz.end(), verticesXyz.begin() + long(3 * std::size_t(old)),
                       verticesXyz.begin() + long(3 * std::size_t(old) + 3));
            normals.insert(normals.end(), vertexNormalsXyz.begin() + long(3 * std::size_t(old)),
                           vertexNormalsXyz.begin() + long(3 * std::size_t(old) + 3));
        }
        indices[k] = newIndex[old];
    }
    return std::make_unique<RayScene>(std::move(xyz), std::move(indices), normals, options);
}

RayScene::RayScene(const TriMesh& mesh, const SceneOptions& options)
    : RayScene(meshVertices(mesh), meshTriangles(mesh), options)
{
}

RayScene::RayScene(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices, const SceneOptions& options)
    : mImpl(std::make_unique<Impl>())
{
    build(std::move(verticesXyz), std::move(triangleIndices), nullptr, options);
}

RayScene::RayScene(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices,
                   const std::vector<float>& vertexNormalsXyz, const SceneOptions& options)
    : mImpl(std::make_unique<Impl>())
{
    checkNormals(vertexNormalsXyz, verticesXyz);
    build(std::move(verticesXyz), std::move(triangleIndices), &vertexNormalsXyz, options);
}

void RayScene::build(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices,
                     const std::vector<float>* vertexNormalsXyz, const SceneOptions& options)
{
    Impl& im = *mImpl;
    const DenormalsFlushed flushed;

    checkTriangleArrays(verticesXyz, triangleIndices, "RayScene");
    const std::size_t nv = verticesXyz.size() / 3;

    im.device = rtcNewDevice(nullptr);
    if (!im.device) {
        std::ostringstream msg;
        msg << "Embree: rtcNewDevice failed: " << errorName(rtcGetDeviceError(nullptr));
        throw std::runtime_error(msg.str());
    }
    rtcSetDeviceErrorFunction(im.device, &recordEmbreeError, &im.errors);

    im.scene = rtcNewScene(im.device);
    im.throwIfError("rtcNewScene");
    // ROBUST: without it rays slip between triangles sharing an edge (measured: 9% of rays
    // aimed at edge midpoints from inside a closed icosphere, ~1 in 10^6 random camera rays),
    // and under OST a leak shows the background or a wall behind as a speckle. Its cost is
    // measured by bench/render_bench. Rays aimed exactly at a vertex can still leak (~2%).
    int flags = RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION;
    if (options.robust) flags |= RTC_SCENE_FLAG_ROBUST;
    rtcSetSceneFlags(im.scene, RTCSceneFlags(flags));
    const RTCBuildQuality quality = options.fastBuild ? RTC_BUILD_QUALITY_LOW : RTC_BUILD_QUALITY_MEDIUM;
    rtcSetSceneBuildQuality(im.scene, quality);
    im.throwIfError("scene setup");

    // Buffers we own and share with Embree (they live as long as the scene); one padding vertex.
    im.vertices.resize(nv + 1, Impl::Vertex{0.f, 0.f, 0.f});
    constexpr double INF = std::numeric_limits<double>::infinity();
    Vec3d lo{INF, INF, INF}, hi{-INF, -INF, -INF};
    for (std::size_t i = 0; i < nv; ++i) {
        const float* p = &verticesXyz[3 * i];
        if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])))
            throw InputError("RayScene: vertex " + std::to_string(i) + " is not finite");
        im.vertices[i] = {p[0], p[1], p[2]};
        lo = {std::min(lo.x, double(p[0])), std::min(lo.y, double(p[1])), std::min(lo.z, double(p[2]))};
        hi = {std::max(hi.x, double(p[0])), std::max(hi.y, double(p[1])), std::max(hi.z, double(p[2]))};
    }
    if (nv == 0) lo = hi = Vec3d{};
    im.boundsMin = lo;
    im.boundsMax = hi;
    im.indices = std::move(triangleIndices);
    im.triangles = uint32_t(im.indices.size() / 3);

    // Vertex normals (normalsOf), or those given: the padding vertex's is zero.
    const std::vector<float> computed = vertexNormalsXyz ? std::vector<float>{} : normalsOf(verticesXyz, im.indices);
    const std::vector<float>& normals = vertexNormalsXyz ? *vertexNormalsXyz : computed;
    im.vertexNormals.assign(nv + 1, Impl::Vertex{0.f, 0.f, 0.f});
    for (std::size_t i = 0; i < nv; ++i) im.vertexNormals[i] = {normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]};
    verticesXyz = {};

    if (im.triangles > 0) {
        RTCGeometry geom = rtcNewGeometry(im.device, RTC_GEOMETRY_TYPE_TRIANGLE);
        im.throwIfError("rtcNewGeometry");
        rtcSetGeometryBuildQuality(geom, quality);
        // itemCount excludes the padding vertex; it is only there to be readable.
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, im.vertices.data(),
                                   0, sizeof(Impl::Vertex), nv);
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, im.indices.data(), 0,
                                   3 * sizeof(uint32_t), im.triangles);
        rtcCommitGeometry(geom);
        rtcAttachGeometry(im.scene, geom);
        rtcReleaseGeometry(geom);
        im.throwIfError("triangle geometry");
    }
    rtcCommitScene(im.scene);
    im.throwIfError("rtcCommitScene");
}

RayScene::~RayScene() = default;

RayHit RayScene::intersect(const Vec3d& origin, const Vec3d& dir, double tnear, double tfar,
                           bool ost) const
{
    return intersect(origin, dir, tnear, tfar, ost, LoopWindow{});
}

RayHit RayScene::intersect(const Vec3d& origin, const Vec3d& dir, double tnear, double tfar, bool ost,
                           const LoopWindow& loop) const
{
    const DenormalsFlushed flushed;
    LoopContext loopContext;
    RTCIntersectContext& context = loopContext.context;
    initIntersectContext(context, ost, false);
    if (ost && loop.active()) {
        if (loop.ownerArcMm->size() != mImpl->triangles)
            throw ParameterError("RayScene::intersect: " + std::to_string(loop.ownerArcMm->size()) +
                                 " triangle owners for a scene of " + std::to_string(mImpl->triangles) + " triangles");
        context.filter = &loopOstFilter;
        loopContext.ownerArc = loop.ownerArcMm->data();
        loopContext.arcLo = float(loop.arcMm - loop.reachMm);
        loopContext.arcHi = float(loop.arcMm + loop.reachMm);
        std::fill(std::begin(loopContext.passedT), std::end(loopContext.passedT), std::numeric_limits<float>::infinity());
    }

    RTCRayHit rh;
    rh.ray.org_x = float(origin.x);
    rh.ray.org_y = float(origin.y);
    rh.ray.org_z = float(origin.z);
    rh.ray.dir_x = float(dir.x);
    rh.ray.dir_y = float(dir.y);
    rh.ray.dir_z = float(dir.z);
    rh.ray.tnear = float(tnear);
    rh.ray.tfar = tfar < double(std::numeric_limits<float>::max()) ? float(tfar)
                                                                    : std::numeric_limits<float>::infinity();
    rh.ray.time = 0.f;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(mImpl->scene, &context, &rh);

    RayHit result;
    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
        result.hit = true;
        result.t = rh.ray.tfar;
        result.primId = rh.hit.primID;
        result.u = rh.hit.u;
        result.v = rh.hit.v;
        result.normal = normalize(Vec3d{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
    }
    return result;
}

Vec3d RayScene::boundsMin() const { return mImpl->boundsMin; }
Vec3d RayScene::boundsMax() const { return mImpl->boundsMax; }
uint32_t RayScene::triangleCount() const { return mImpl->triangles; }
uint32_t RayScene::vertexCount() const { return uint32_t(mImpl->vertices.size() - 1); }

Vec3d RayScene::vertex(uint32_t i) const
{
    if (i >= vertexCount()) throw ParameterError("RayScene::vertex: index " + std::to_string(i) + " out of range");
    const Impl::Vertex& v = mImpl->vertices[i];
    return {v.x, v.y, v.z};
}

std::array<uint32_t, 3> RayScene::triangle(uint32_t f) const
{
    if (f >= mImpl->triangles)
        throw ParameterError("RayScene::triangle: index " + std::to_string(f) + " out of range");
    const uint32_t* t = &mImpl->indices[3 * std::size_t(f)];
    return {t[0], t[1], t[2]};
}

Vec3d RayScene::shadingNormal(uint32_t primId, double u, double v, bool smooth) const
{
    const Impl& im = *mImpl;
    if (primId >= im.triangles) {
        std::ostringstream msg;
        msg << "RayScene::shadingNormal: triangle " << primId << " out of range (" << im.triangles
            << " triangles)";
        throw ParameterError(msg.str());
    }
    const uint32_t* t = &im.indices[3 * std::size_t(primId)];
    auto vec = [](const Impl::Vertex& p) { return Vec3d{p.x, p.y, p.z}; };
    if (!smooth) {
        const Vec3d a = vec(im.vertices[t[0]]);
        return normalize(cross(vec(im.vertices[t[1]]) - a, vec(im.vertices[t[2]]) - a));
    }
    return normalize(vec(im.vertexNormals[t[0]]) * (1.0 - u - v) + vec(im.vertexNormals[t[1]]) * u +
                     vec(im.vertexNormals[t[2]]) * v);
}

} // namespace flyover
