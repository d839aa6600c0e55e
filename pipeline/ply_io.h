/// @file ply_io.h
/// @brief PLY artifacts: the binary triangle-mesh writer (OpenMesh's bytes) and the readers.
#pragma once

#include "surface/mesh_types.h"

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace flyover {

/// A binary little-endian triangle PLY: float x y z and optional uchar properties per vertex,
/// faces as `list uchar int vertex_indices` of 3 (the layout of OpenMesh's binary writer when
/// there are no comments and no properties).
struct TrianglePly {
    std::size_t vertices = 0, faces = 0;
    std::vector<std::string> comments;      ///< one `comment` line each, after the format line
    std::vector<std::string> vertexUchars;  ///< names of the per-vertex uchar properties after x y z
    /// Vertex v's position and its vertexUchars.size() uchar values.
    std::function<void(std::size_t v, float* xyz, uint8_t* uchars)> vertex;
    /// Face f's three vertex indices; false when it is not a triangle.
    std::function<bool(std::size_t f, int32_t* idx)> face;
};

/// Writes `ply` into `file` in one write (built in memory; not atomic: wrap it in
/// writeAtomically). @return false, writing nothing, when a face is not a triangle.
/// @throw std::runtime_error on a big-endian host or a failed write.
bool writeTrianglePly(const std::string& file, const TrianglePly& ply);

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
