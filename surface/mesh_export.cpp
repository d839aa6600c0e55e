// GCC 12 reports -Wmaybe-uninitialized inside OpenMesh's PropertyT<Vec3f>::push_back (its
// VectorT default constructor leaves components uninitialised on purpose), instantiated here
// by the readers. Pragma scope is by source location: this silences only the headers.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "surface/mesh_export.h"

#include "surface/openmesh_log.h"
#include "volume/error.h"

#include <OpenMesh/Core/IO/MeshIO.hh>

#include <filesystem>
#pragma GCC diagnostic pop

namespace flyover {

bool isMeshFileFormat(const std::string& extension)
{
    return extension == ".ply" || extension == ".obj" || extension == ".stl" || extension == ".off";
}

bool isBinaryMeshFormat(const std::string& extension)
{
    return isMeshFileFormat(extension) && extension != ".obj";
}

void writeMeshFile(const TriMesh& mesh, const std::string& path)
{
    const std::string ext = std::filesystem::path(path).extension().string();
    if (!isMeshFileFormat(ext))
        throw InputError(path + ": unsupported mesh format '" + ext + "' (use .ply, .obj, .stl or .off)");
    OpenMesh::IO::Options options;
    if (isBinaryMeshFormat(ext)) options += OpenMesh::IO::Options::Binary;
    bool written = false;
    {
        // The writers report progress on omlog/omout; failures still surface as `false`.
        const ScopedOpenMeshMute mute(ScopedOpenMeshMute::LOG | ScopedOpenMeshMute::OUT);
        written = OpenMesh::IO::write_mesh(mesh, path, options);
    }
    if (!written) throw InputError(path + ": OpenMesh could not write the mesh");
}

TriMesh readMeshFile(const std::string& path)
{
    TriMesh mesh;
    bool read = false;
    {
        const ScopedOpenMeshMute mute(ScopedOpenMeshMute::LOG | ScopedOpenMeshMute::OUT);
        OpenMesh::IO::Options options;  // binary or text: the readers detect it
        read = OpenMesh::IO::read_mesh(mesh, path, options);
    }
    if (!read) throw InputError(path + ": OpenMesh could not read a mesh");
    if (mesh.n_faces() == 0) throw InputError(path + ": the mesh has no faces");
    return mesh;
}

} // namespace flyover
