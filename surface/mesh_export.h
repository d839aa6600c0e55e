/// @file mesh_export.h
/// @brief A lumen surface in the formats other tools load (.ply, .obj, .stl, .off) through
///        OpenMesh's writers and readers: binary where the format allows (OBJ is text only),
///        without OpenMesh's console chatter ("[STLWriter] : write binary file").
///
/// Writes exactly the path given: atomic replacement (temporary name, rename) is the
/// caller's business (pipeline/). STL stores unshared triangle corners: reading it back
/// merges corners by position, which restores the mesh when no two vertices coincide.
#pragma once

#include "surface/mesh_types.h"

#include <string>

namespace flyover {

/// True for the extensions writeMeshFile accepts: ".ply", ".obj", ".stl", ".off".
bool isMeshFileFormat(const std::string& extension);

/// True when writeMeshFile writes this format as binary (all but ".obj").
bool isBinaryMeshFormat(const std::string& extension);

/// Writes `mesh` to `path`, the format chosen by the extension (lower case).
/// @throw InputError naming the path for an unsupported extension or a failed write
void writeMeshFile(const TriMesh& mesh, const std::string& path);

/// Reads a mesh written by writeMeshFile (or any triangle mesh OpenMesh reads).
/// @throw InputError naming the path when it cannot be read or has no faces
TriMesh readMeshFile(const std::string& path);

} // namespace flyover
