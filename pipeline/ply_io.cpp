#include "pipeline/ply_io.h"

#include "pipeline/atomic_write.h"
#include "volume/error.h"

#include <OpenMesh/Core/IO/MeshIO.hh>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <vector>

namespace fs = std::filesystem;

namespace flyover {

namespace {

bool littleEndianHost()
{
    const uint16_t probe = 1;
    uint8_t firstByte = 0;
    std::memcpy(&firstByte, &probe, 1);
    return firstByte == 1;
}


/// A triangle mesh without deleted elements as a TrianglePly (false for any other mesh, which
/// then goes through OpenMesh): the bytes OpenMesh's binary PLY writer makes of it (x y z per
/// vertex in index order, then per face the count 3 and the vertex indices in its face-vertex
/// circulation order), built in memory and written at once instead of one stream write per
/// value (the full phantom's 16.7 MB: ~4.8 M writes).
bool writeMeshPly(const std::string& tmp, const TriMesh& mesh)
{
    const std::size_t nv = mesh.n_vertices(), nf = mesh.n_faces();
    if (mesh.has_vertex_status())
        for (std::size_t v = 0; v < nv; ++v)
            if (mesh.status(OpenMesh::VertexHandle(int(v))).deleted()) return false;
    if (mesh.has_face_status())
        for (std::size_t f = 0; f < nf; ++f)
            if (mesh.status(OpenMesh::FaceHandle(int(f))).deleted()) return false;
    TrianglePly ply;
    ply.vertices = nv;
    ply.faces = nf;
    ply.vertex = [&mesh](std::size_t v, float* xyz, uint8_t*) {
        const TriMesh::Point& p = mesh.point(OpenMesh::VertexHandle(int(v)));
        xyz[0] = p[0], xyz[1] = p[1], xyz[2] = p[2];
    };
    ply.face = [&mesh](std::size_t f, int32_t* idx) {
        int n = 0;
        for (auto it = mesh.cfv_iter(OpenMesh::FaceHandle(int(f))); it.is_valid(); ++it) {
            if (n == 3) return false;
            idx[n++] = it->idx();
        }
        return n == 3;
    };
    return writeTrianglePly(tmp, ply);
}

} // namespace

bool writeTrianglePly(const std::string& file, const TrianglePly& ply)
{
    static_assert(sizeof(float) == 4 && sizeof(int32_t) == 4, "PLY needs 32-bit float and int");
    if (!littleEndianHost()) throw std::runtime_error(file + ": the PLY writer assumes a little-endian machine");
    std::string header = "ply\nformat binary_little_endian 1.0\n";
    for (const std::string& c : ply.comments) header += "comment " + c + "\n";
    header += "element vertex " + std::to_string(ply.vertices) + "\nproperty float x\nproperty float y\nproperty float z\n";
    for (const std::string& name : ply.vertexUchars) header += "property uchar " + name + "\n";
    header += "element face " + std::to_string(ply.faces) + "\nproperty list uchar int vertex_indices\nend_header\n";
    const std::size_t uchars = ply.vertexUchars.size(), vertexBytes = 12 + uchars;
    std::vector<char> bytes(header.size() + ply.vertices * vertexBytes + ply.faces * 13);
    char* out = bytes.data();
    std::memcpy(out, header.data(), header.size());
    out += header.size();
    std::vector<uint8_t> values(uchars);
    for (std::size_t v = 0; v < ply.vertices; ++v, out += vertexBytes) {
        float xyz[3];
        ply.vertex(v, xyz, values.data());
        std::memcpy(out, xyz, 12);
        if (uchars) std::memcpy(out + 12, values.data(), uchars);
    }
    for (std::size_t f = 0; f < ply.faces; ++f, out += 13) {
        int32_t idx[3];
        if (!ply.face(f, idx)) return false;
        out[0] = char(3);
        std::memcpy(out + 1, idx, sizeof idx);
    }
    writeFileBytes(file, bytes.data(), bytes.size());
    return true;
}

void writeMesh(const std::string& path, const TriMesh& mesh)
{
    writeAtomically(path, [&](const std::string& tmp) {
        if (littleEndianHost() && writeMeshPly(tmp, mesh)) return;
        OpenMesh::IO::Options opt = OpenMesh::IO::Options::Binary;
        if (!OpenMesh::IO::write_mesh(mesh, tmp, opt))
            throw InputError(path + ": OpenMesh could not write the mesh");
    });
}

void writeMeshWithOpenMesh(const std::string& path, const TriMesh& mesh)
{
    OpenMesh::IO::Options opt = OpenMesh::IO::Options::Binary;
    if (!OpenMesh::IO::write_mesh(mesh, path, opt)) throw InputError(path + ": OpenMesh could not write the mesh");
}

TriMesh readMesh(const std::string& path)
{
    if (!fs::exists(path)) throw InputError(path + ": no such file");
    TriMesh mesh;
    OpenMesh::IO::Options opt = OpenMesh::IO::Options::Binary;
    if (!OpenMesh::IO::read_mesh(mesh, path, opt))
        throw InputError(path + ": OpenMesh could not read the mesh");
    return mesh;
}

/// Reads the vertices and triangles of a binary little-endian PLY with exactly float x, y, z
/// per vertex and `list uchar int vertex_indices` of 3 per face (what writeMesh produces),
/// without building a mesh topology: that takes most of a second for a million triangles, and
/// the renderer needs none. @return false when the file has another layout (the caller then
/// reads it with the general reader).
bool readPlainPly(const std::string& path, std::vector<float>& xyz, std::vector<uint32_t>& tris)
{
    const uint16_t probe = 1;
    uint8_t firstByte = 0;
    std::memcpy(&firstByte, &probe, 1);
    const bool hostIsLittleEndian = firstByte == 1;
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open for reading");
    std::string line;
    std::vector<std::string> header;
    while (std::getline(in, line)) {
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.rfind("comment", 0) == 0 || line.rfind("obj_info", 0) == 0) continue;
        header.push_back(line);
        if (line == "end_header" || header.size() > 16) break;
    }
    long long nv = -1, nf = -1;
    if (header.size() != 9 || header[0] != "ply" || header[1] != "format binary_little_endian 1.0" ||
        std::sscanf(header[2].c_str(), "element vertex %lld", &nv) != 1 || header[3] != "property float x" ||
        header[4] != "property float y" || header[5] != "property float z" ||
        std::sscanf(header[6].c_str(), "element face %lld", &nf) != 1 ||
        (header[7] != "property list uchar int vertex_indices" && header[7] != "property list uchar int vertex_index") ||
        header[8] != "end_header" || !hostIsLittleEndian)
        return false;
    if (nv < 0 || nf < 0 || nv >= (1LL << 32) || nf > (1LL << 30)) return false;
    xyz.resize(std::size_t(3 * nv));
    in.read(reinterpret_cast<char*>(xyz.data()), std::streamsize(xyz.size() * sizeof(float)));
    std::vector<char> faces(std::size_t(nf) * 13);
    in.read(faces.data(), std::streamsize(faces.size()));
    if (!in) throw InputError(path + ": truncated PLY");
    tris.resize(std::size_t(3 * nf));
    for (std::size_t f = 0; f < std::size_t(nf); ++f) {
        const char* rec = &faces[f * 13];
        if (uint8_t(rec[0]) != 3) return false;  // not all triangles
        int32_t idx[3];
        std::memcpy(idx, rec + 1, sizeof idx);
        for (int k = 0; k < 3; ++k) {
            if (idx[k] < 0 || idx[k] >= nv) throw InputError(path + ": face " + std::to_string(f) + " has a bad vertex index");
            tris[3 * f + std::size_t(k)] = uint32_t(idx[k]);
        }
    }
    return true;
}

} // namespace flyover
