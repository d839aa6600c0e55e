/// @file ray_scene_impl.h
/// @brief Private to render/: the Embree objects behind RayScene, the OST filter and the
///        per-thread floating-point guard, shared by ray_scene.cpp and render_view.cpp.
#pragma once

#include "render/ray_scene.h"

#include <embree3/rtcore.h>

#include <xmmintrin.h>
#include <pmmintrin.h>

#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace flyover {

/// Embree reports errors through a callback; we record the first one and throw it from our
/// own code after the call returns (throwing through Embree's C API is not safe).
struct EmbreeErrorState {
    std::mutex mutex;
    RTCError code = RTC_ERROR_NONE;
    std::string message;
};

struct RayScene::Impl {
    /// Vertex layout of the shared buffer: float3, 12-byte stride.
    struct Vertex {
        float x, y, z;
    };

    EmbreeErrorState errors;
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    /// n + 1 vertices: Embree reads up to 16 bytes past the last vertex of a shared buffer.
    std::vector<Vertex> vertices;
    std::vector<uint32_t> indices;  ///< 3 per triangle; triangle i is mesh face i
    /// Unit vertex normals for smooth shading, same layout as `vertices` (zero for a vertex
    /// whose faces all have zero area).
    std::vector<Vertex> vertexNormals;
    uint32_t triangles = 0;
    Vec3d boundsMin, boundsMax;

    Impl() = default;
    ~Impl();
    Impl(const Impl&) = delete;
    Impl& operator=(const Impl&) = delete;

    /// Throws std::runtime_error naming `what` if Embree reported an error since the last call.
    void throwIfError(const char* what);
};

/// Context filter for one-sided transparency: a hit is rejected when the ray leaves the
/// face's front side, dot(ray.dir, Ng) > 0, Ng being Embree's geometric normal
/// (v1 - v0) x (v2 - v0) — the same convention as the mesh's inward normals.
void ostFilter(const RTCFilterFunctionNArguments* args);

/// The context of loop-local OST (render_view.h LoopWindow): Embree hands the filter the
/// context's address, so the window travels with it. A hit on a front face whose owner's arc
/// lies outside [arcLo, arcHi] is passed through; passedT[ray id] keeps the nearest such hit
/// (ray ids are the lanes of a packet, 0..15).
struct LoopContext {
    RTCIntersectContext context;  ///< first member: the filter casts back from it
    const float* ownerArc = nullptr;
    float arcLo = 0.0f, arcHi = 0.0f;
    float passedT[16];
};

/// OST and the loop window of a LoopContext in one context filter.
void loopOstFilter(const RTCFilterFunctionNArguments* args);

/// An intersect context with the OST filter attached only when `ost` is set (plain rendering
/// pays nothing).
inline void initIntersectContext(RTCIntersectContext& context, bool ost, bool coherent)
{
    rtcInitIntersectContext(&context);
    context.flags = coherent ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
    context.filter = ost ? &ostFilter : nullptr;
}

/// Sets flush-to-zero and denormals-are-zero for the current thread (Embree's requirement for
/// speed) and restores the caller's MXCSR afterwards, so a TBB task that happens to run on a
/// user thread leaves its floating-point mode untouched.
class DenormalsFlushed {
public:
    DenormalsFlushed() : mSaved(_mm_getcsr())
    {
        _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
        _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
    }
    ~DenormalsFlushed() { _mm_setcsr(mSaved); }
    DenormalsFlushed(const DenormalsFlushed&) = delete;
    DenormalsFlushed& operator=(const DenormalsFlushed&) = delete;

private:
    unsigned int mSaved;
};

} // namespace flyover
