/// @file ray_scene.h
/// @brief An Embree scene over one triangle mesh (RAII over RTCDevice and RTCScene), with
///        one-sided transparency: hits on faces whose normal points away from the ray
///        origin (dot(dir, Ng) > 0) are discarded by an intersection filter.
#pragma once

#include "surface/mesh_types.h"
#include "volume/vec3.h"

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace flyover {

struct RayHit {
    bool hit = false;
    double t = 0;          ///< ray parameter of the hit (in units of |dir|)
    uint32_t primId = 0;   ///< triangle index (face index of the mesh)
    double u = 0, v = 0;   ///< barycentrics of the hit: weights of the face's 2nd and 3rd vertex
    Vec3d normal;          ///< unit geometric normal of the hit face (as wound)
};

struct SceneOptions {
    /// Embree's robust mode: watertight ray/triangle tests, so rays through shared edges do not
    /// slip between triangles (a leak shows as a background speckle under OST). Costs about
    /// 10% of tracing speed (bench/render_bench measures it); keep it on for images.
    bool robust = true;
    /// Embree's LOW build quality (a Morton BVH) instead of MEDIUM: faster to build, slower to
    /// trace; for a scene that few rays will meet (the first pair's). The hits are the same.
    bool fastBuild = false;
};

/// The checks RayScene's array constructors make: coordinates and indices in threes, sizes that
/// fit Embree's 32-bit indices, every index naming a vertex. @throw InputError starting "where: ".
void checkTriangleArrays(const std::vector<float>& verticesXyz, const std::vector<uint32_t>& triangleIndices,
                         const std::string& where);

/// The arrays RayScene's second constructor takes, from a mesh: x, y, z per vertex and three
/// vertex indices per face (in the order of the face-vertex circulator, as RayScene(mesh) uses).
/// @throw InputError for deleted faces, faces that are not triangles or a mesh too large.
void triMeshArrays(const TriMesh& mesh, std::vector<float>& verticesXyz, std::vector<uint32_t>& triangleIndices);

/// The smooth-shading normals RayScene computes for its vertices (x, y, z per vertex): the sum of
/// the unnormalised normals of the incident triangles, normalised (zero where that sum is zero).
/// @throw InputError for an index out of range or coordinates not in threes.
std::vector<float> smoothVertexNormals(const std::vector<float>& verticesXyz,
                                       const std::vector<uint32_t>& triangleIndices);

/// Loop-local OST: the view shows only the wall of the stretch of colon it flies. A hit on a
/// triangle whose owner (render/loop_ownership.h: the part of the path that reaches it through
/// the lumen) lies more than `reachMm` along the path from the view's own place `arcMm` is
/// passed through like a back face. Triangles without an owner (NaN) are never passed through.
struct LoopWindow {
    const std::vector<float>* ownerArcMm = nullptr;  ///< per scene triangle; null: off
    double arcMm = 0.0;                              ///< the view's place on the path (mm)
    double reachMm = 0.0;                            ///< 0: off (the thesis' OST)
    bool active() const { return ownerArcMm != nullptr && reachMm > 0.0; }
};

class RayScene;

/// A scene of some of a surface's triangles (`triangleIndices`, indices into `verticesXyz`) that
/// holds only the vertices they use and shades them with the surface's `vertexNormalsXyz`: the
/// same hits, barycentrics and shading as the scene of the whole surface gives on them (the
/// triangles are numbered in the order given, the vertices in the order of first use).
/// @throw InputError as RayScene's constructors.
std::unique_ptr<RayScene> sceneOfTriangles(const std::vector<float>& verticesXyz,
                                           const std::vector<float>& vertexNormalsXyz,
                                           const std::vector<uint32_t>& triangleIndices,
                                           const SceneOptions& options = {});

class RayScene {
public:
    /// Copies the mesh into Embree buffers, builds the BVH (MEDIUM quality) and computes
    /// per-vertex normals for smooth shading (area-weighted face normals, same orientation as
    /// the faces: into the lumen).
    /// @throw std::runtime_error with Embree's message when the device or scene fails.
    /// @throw InputError for faces that are not triangles or deleted faces.
    explicit RayScene(const TriMesh& mesh, const SceneOptions& options = {});
    /// The same from plain arrays (x, y, z per vertex; three vertex indices per triangle, wound
    /// as the mesh's faces): for callers that read a mesh file without building its topology.
    /// @throw InputError for an index out of range or a non-finite vertex.
    RayScene(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices, const SceneOptions& options = {});
    /// The same with the vertex normals given (x, y, z per vertex, as smoothVertexNormals()
    /// returns them): a scene of some of a surface's triangles (a cull) that shades exactly as
    /// the scene of the whole surface, whose normals these are.
    /// @throw InputError when there are not three normal coordinates per vertex.
    RayScene(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices,
             const std::vector<float>& vertexNormalsXyz, const SceneOptions& options = {});
    ~RayScene();
    RayScene(const RayScene&) = delete;
    RayScene& operator=(const RayScene&) = delete;

    /// Closest hit of one ray with t in [tnear, tfar]; `ost` discards back faces.
    RayHit intersect(const Vec3d& origin, const Vec3d& dir, double tnear, double tfar,
                     bool ost) const;
    /// The same with loop-local OST (`loop` active, with `ost`): other loops' walls passed.
    /// @throw ParameterError when the window's owners do not match the scene's triangles
    RayHit intersect(const Vec3d& origin, const Vec3d& dir, double tnear, double tfar, bool ost,
                     const LoopWindow& loop) const;

    Vec3d boundsMin() const;
    Vec3d boundsMax() const;
    uint32_t triangleCount() const;
    uint32_t vertexCount() const;
    /// Vertex i (mm) and the three vertex indices of triangle f, as given to the scene.
    Vec3d vertex(uint32_t i) const;
    std::array<uint32_t, 3> triangle(uint32_t f) const;

    /// Unit shading normal at a hit: the vertex normals interpolated with (u, v) (smooth), or
    /// the geometric normal of the face when `smooth` is false.
    Vec3d shadingNormal(uint32_t primId, double u, double v, bool smooth = true) const;

    struct Impl;
    const Impl& impl() const { return *mImpl; }

private:
    /// Both array constructors: `vertexNormalsXyz` null computes the normals.
    void build(std::vector<float> verticesXyz, std::vector<uint32_t> triangleIndices,
               const std::vector<float>* vertexNormalsXyz, const SceneOptions& options);

    std::unique_ptr<Impl> mImpl;
};

} // namespace flyover
