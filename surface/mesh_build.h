/// @file mesh_build.h
/// @brief OpenMesh connectivity from a face list, the same as add_face called face by face.
#pragma once

#include "surface/mesh_types.h"

#include <array>
#include <cstdint>
#include <vector>

namespace flyover {

/// Adds `faces` (vertex indices into `mesh`'s vertices, which must exist already; the mesh
/// must have no edges or faces yet) to `mesh`, in order, with the result of calling
/// `mesh.add_face(a, b, c)` for each one: the same faces refused (a repeated vertex, a
/// complex vertex or edge, a failed patch re-linking), the same edges, halfedges, faces and
/// every handle among them (next, prev, vertex and face halfedges) in the same order. The
/// incremental build runs on flat arrays instead of OpenMesh's property containers (one
/// resize per property instead of one per new edge and face) and is copied in at the end.
/// Returns the number of faces refused.
int64_t addFacesLikeOpenMesh(TriMesh& mesh, const std::vector<std::array<int, 3>>& faces);

} // namespace flyover
