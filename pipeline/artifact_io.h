/// @file artifact_io.h
/// @brief On-disk artifacts of a study: atomic writes (temporary name, then rename),
///        content digests, and the readers/writers of each artifact type.
#pragma once

#include "render/render_view.h"
#include "surface/mesh_types.h"
#include "volume/centerline_types.h"

#include <openvdb/openvdb.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace flyover {

/// Crash-test hook: when the environment variable FLYOVER_CRASH_AT equals `point`, the
/// process kills itself with SIGKILL right there (as `kill -9` would). Used by the tests to
/// crash at exact moments (mid-write, between a cache object and its record); a no-op
/// otherwise.
void crashPoint(const char* point);

/// The machine, not the input, failed while storing a result (disk full, quota, I/O error,
/// out of memory, a stale network file handle): worth retrying, possibly elsewhere.
/// `flyover` exits with EX_TEMPFAIL (75) for it (see pipeline/stage_command.h).
struct TransientError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// True for errno values that say the machine, not the input, failed (ENOSPC, EDQUOT, EIO,
/// ENOMEM, ESTALE, ETIMEDOUT).
bool isTransientErrno(int error);

/// Writes a file atomically: `write` receives a temporary path in the same folder (with the
/// same extension, for writers that pick the format by extension), which is then renamed
/// onto `path`. On any exception the temporary file is removed and the exception rethrown, as a
/// TransientError naming `path` when errno says the disk or the machine failed (full, I/O).
void writeAtomically(const std::string& path, const std::function<void(const std::string& tmpPath)>& write);

/// xxHash3-128 of a file's content as 32 hex digits. @throw InputError if unreadable.
std::string fileDigest(const std::string& path);
/// xxHash3-128 of a string, 32 hex digits.
std::string stringDigest(const std::string& text);

void writeJson(const std::string& path, const nlohmann::json& j);
/// @throw InputError naming the file when it is missing or not valid JSON.
nlohmann::json readJson(const std::string& path);

/// Writes grids to a compressed .vdb file (readable by vdb_print).
void writeGrids(const std::string& path, const openvdb::GridPtrVec& grids);
/// Reads one named grid. @throw InputError naming the file and grid.
openvdb::GridBase::Ptr readGrid(const std::string& path, const std::string& gridName);
/// The same with OpenVDB's delayed loading: the tree's topology is read now, each leaf's values
/// only when first accessed (from the file, kept open; a study's files are replaced by rename,
/// never rewritten in place). For a caller that reads a small part of a large grid's values
/// (the part surfaces: a narrow band around the surfaces of a 1024^3 CT).
openvdb::GridBase::Ptr readGridDelayed(const std::string& path, const std::string& gridName);

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

/// PNG file bytes of an 8-bit RGB image: every row filtered with Up, one IDAT deflated by ISA-L
/// (level 1, zlib stream). The frames' writer and the viewer's answers. @throw InputError.
std::string encodePng(const RgbImage& image);
/// 8-bit grayscale PNG of width x height bytes, top row first, encoded as encodePng.
std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray);
void writePng(const std::string& path, const RgbImage& image);
/// Reads an 8-bit RGB or RGBA PNG (alpha dropped). Plain 8-bit RGB files (the frames') are
/// decoded by decodePlainRgbPng, every other file and any file it declines by libpng.
/// @throw InputError.
RgbImage readPng(const std::string& path);
/// The pixels of a plain PNG file's bytes: 8-bit RGB, not interlaced, only IHDR, IDAT, IEND and
/// text, time and pHYs chunks, every critical chunk's CRC right and the zlib stream whole
/// (ISA-L inflate, Adler-32 checked) and exactly one image long. @return false for any other
/// or damaged file (readPng leaves those to libpng); true: the values libpng would return.
bool decodePlainRgbPng(const std::string& bytes, RgbImage& out);

/// centerline.json: documented schema "flyover.centerline/1", LPS mm, columnar arrays.
nlohmann::json centerlineToJson(const Centerline& centerline);
Centerline centerlineFromJson(const nlohmann::json& j, const std::string& source);

} // namespace flyover
