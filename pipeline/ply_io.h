/// @file ply_io.h
/// @brief PLY artifacts: the binary triangle-mesh writer (OpenMesh's bytes) and the readers.
#pragma once

#include "surface/mesh_types.h"

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// Binary PLY, the bytes of OpenMesh's writer: a triangle mesh without deleted elements is
/// laid out in memory and written at once (the mesh stage's surface.ply is on the way to the
/// first pair), any other mesh goes through OpenMesh. @throw InputError.
void writeMesh(const std::string& path, const TriMesh& mesh);
/// OpenMesh's binary PLY writer itself, written in place (no temporary): what writeMesh's
/// bytes are tested against.
void writeMeshWithOpenMesh(const std::string& path, const TriMesh& mesh);
TriMesh readMesh(const std::string& path);

/// Reads the vertices and triangles of a binary little-endian PLY with exactly float x, y, z
/// per vertex and `list uchar int vertex_indices` of 3 per face (what writeMesh produces),
/// without building a mesh topology (for RayScene's array constructor).
/// @return false when the file has another layout (read it with readMesh then).
/// @throw InputError when it is unreadable, truncated or has a bad vertex index.
bool readPlainPly(const std::string& path, std::vector<float>& xyz, std::vector<uint32_t>& tris);

} // namespace flyover
