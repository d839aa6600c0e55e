/// @file ray_scene.h
/// @brief An Embree scene over one triangle mesh (RAII over RTCDevice and RTCScene), with
///        one-sided transparency: hits on faces whose normal points away from the ray
///        origin (dot(dir, Ng) > 0) are discarded by an intersection filter.
#pragma once

#include "surface/mesh_types.h"
#include "volume/vec3.h"

#include <cstdint>
#include <memory>

namespace flyover {

struct RayHit {
    bool hit = false;
    double t = 0;          ///< ray parameter of the hit (in units of |dir|)
    uint32_t primId = 0;   ///< triangle index (face index of the mesh)
    Vec3d normal;          ///< unit geometric normal of the hit face (as wound)
};

class RayScene {
public:
    /// @throw std::runtime_error with Embree's message when the device or scene fails.
    explicit RayScene(const TriMesh& mesh);
    ~RayScene();
    RayScene(const RayScene&) = delete;
    RayScene& operator=(const RayScene&) = delete;

    /// Closest hit of one ray with t in [tnear, tfar]; `ost` discards back faces.
    RayHit intersect(const Vec3d& origin, const Vec3d& dir, double tnear, double tfar,
                     bool ost) const;

    Vec3d boundsMin() const;
    Vec3d boundsMax() const;
    uint32_t triangleCount() const;

    struct Impl;
    const Impl& impl() const { return *mImpl; }

private:
    std::unique_ptr<Impl> mImpl;
};

} // namespace flyover
