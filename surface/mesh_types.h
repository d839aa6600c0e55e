/// @file mesh_types.h
/// @brief The triangle mesh type passed from surface/ to render/ (OpenMesh only, no OpenVDB).
///
/// Convention: a face's normal is (v1 - v0) x (v2 - v0) (OpenMesh's and Embree's), and on
/// a lumen surface it points INTO the lumen (towards the air). That is what makes
/// one-sided transparency work.
#pragma once

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

namespace flyover {

struct MeshTraits : public OpenMesh::DefaultTraits {
    using Point = OpenMesh::Vec3f;
    using Normal = OpenMesh::Vec3f;
};
using TriMesh = OpenMesh::TriMesh_ArrayKernelT<MeshTraits>;

} // namespace flyover
