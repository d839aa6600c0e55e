/// @file mesh_types.h
/// @brief The triangle mesh type passed from surface/ to render/ (OpenMesh only, no OpenVDB).
///
/// Convention: a face's normal is (v1 - v0) x (v2 - v0) (OpenMesh's and Embree's), and on
/// a lumen surface it points INTO the lumen (towards the air). That is what makes
/// one-sided transparency work.
#pragma once

// GCC 12 warns (-Wmaybe-uninitialized) inside OpenMesh's PropertyT<Vec3f>::push_back, whose
// VectorT default constructor leaves components uninitialised on purpose. Pragma scope is by
// source location: ignoring it around OpenMesh's headers silences only third-party code, for
// every file that takes OpenMesh through this header (include it before any other OpenMesh one).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#pragma GCC diagnostic pop

namespace flyover {

struct MeshTraits : public OpenMesh::DefaultTraits {
    using Point = OpenMesh::Vec3f;
    using Normal = OpenMesh::Vec3f;
};
using TriMesh = OpenMesh::TriMesh_ArrayKernelT<MeshTraits>;

} // namespace flyover
