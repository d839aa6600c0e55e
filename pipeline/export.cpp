#include "pipeline/export.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"

#include <OpenMesh/Core/IO/MeshIO.hh>

#include <filesystem>

namespace fs = std::filesystem;

namespace flyover {

void exportMesh(const std::string& studyDir, const std::string& outPath)
{
    const std::string ext = fs::path(outPath).extension().string();
    if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".off")
        throw InputError(outPath + ": unsupported mesh format '" + ext + "' (use .ply, .obj, .stl or .off)");
    const TriMesh mesh = readMesh((fs::path(studyDir) / "surface.ply").string());
    writeAtomically(outPath, [&](const std::string& tmp) {
        OpenMesh::IO::Options opt;
        if (ext != ".obj") opt += OpenMesh::IO::Options::Binary;  // OBJ is text only
        if (!OpenMesh::IO::write_mesh(mesh, tmp, opt))
            throw InputError(outPath + ": OpenMesh could not write the mesh");
    });
}

} // namespace flyover
