#include "pipeline/artifact_io.h"

#include "pipeline/deferred_writes.h"
#include "pipeline/grid_write.h"

#include "volume/error.h"
#include "volume/fd_write.h"
#include "volume/image.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <isa-l/crc.h>
#include <isa-l/igzip_lib.h>
#include <png.h>
#include <xxhash.h>

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <new>
#include <stdexcept>
#include <system_error>
#include <fcntl.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace flyover {

namespace {

std::string hex128(XXH128_hash_t h)
{
    char buf[33];
    std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(h.high64),
                  static_cast<unsigned long long>(h.low64));
    return buf;
}

} // namespace

void crashPoint(const char* point)
{
    static const char* target = std::getenv("FLYOVER_CRASH_AT");
    if (target && std::strcmp(target, point) == 0) ::raise(SIGKILL);
}

namespace {

thread_local DeferredWrites* tDeferred = nullptr;

void fsyncFile(const std::string& path)
{
    if (FILE* f = std::fopen(path.c_str(), "rb")) {
        ::fsync(fileno(f));
        std::fclose(f);
    }
}

} // namespace

DeferredWrites::Scope::Scope(DeferredWrites* writes) : mPrevious(tDeferred) { tDeferred = writes; }
DeferredWrites::Scope::~Scope() { tDeferred = mPrevious; }

DeferredWrites* DeferredWrites::active() { return tDeferred; }

DeferredWrites::~DeferredWrites()
{
    std::error_code ec;
    for (const auto& [tmp, target] : mFiles) fs::remove(tmp, ec);
}

void DeferredWrites::add(const std::string& tmpPath, const std::string& path) { mFiles.emplace_back(tmpPath, path); }

std::string DeferredWrites::pendingFile(const std::string& path) const
{
    for (auto it = mFiles.rbegin(); it != mFiles.rend(); ++it)
        if (it->second == path) return it->first;
    return {};
}

void DeferredWrites::rename()
{
    for (const auto& [tmp, target] : mFiles) {
        crashPoint("atomic-write:before-rename");
        fs::rename(tmp, target);
        mRenamed.push_back(target);
    }
    mFiles.clear();
}

void DeferredWrites::sync()
{
    for (const auto& target : mRenamed) fsyncFile(target);
    mRenamed.clear();
}

void DeferredWrites::addReportPart(std::function<void(nlohmann::json&)> complete)
{
    mReportParts.push_back(std::move(complete));
}

void DeferredWrites::completeReport(nlohmann::json& report)
{
    for (const auto& part : mReportParts) part(report);
    mReportParts.clear();
}

std::string writtenFile(const std::string& path)
{
    if (tDeferred) {
        const std::string pending = tDeferred->pendingFile(path);
        if (!pending.empty()) return pending;
    }
    return path;
}

void writeAtomically(const std::string& path, const std::function<void(const std::string&)>& write)
{
    const fs::path target(path);
    const fs::path tmp = target.parent_path() /
                         (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string());
    try {
        errno = 0;  // what a failing writer leaves here says why (see the catch below)
        write(tmp.string());
        if (tDeferred) {  // write-behind: the fsync and the rename come with finish()
            tDeferred->add(tmp.string(), path);
            return;
        }
        // Flush the data to disk before the rename makes it visible: a crash must never leave
        // a renamed but empty file.
        fsyncFile(tmp.string());
        crashPoint("atomic-write:before-rename");
        fs::rename(tmp, target);
    } catch (const TransientError&) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw;
    } catch (const std::exception& e) {
        // Writers report "cannot write" without the cause: errno still holds it (a full disk
        // is not a bad input, and a workflow engine should retry it).
        const int error = errno;
        const auto* sys = dynamic_cast<const std::system_error*>(&e);
        const int code = sys ? sys->code().value() : error;
        std::error_code ec;
        fs::remove(tmp, ec);
        if (isTransientErrno(code) || dynamic_cast<const std::bad_alloc*>(&e))
            throw TransientError(path + ": cannot write: " + (dynamic_cast<const std::bad_alloc*>(&e)
                                                                  ? std::string("out of memory")
                                                                  : std::strerror(code)));
        throw;
    }
}

bool isTransientErrno(int error)
{
    switch (error) {
    case ENOSPC: case EDQUOT: case EIO: case ENOMEM: case ESTALE: case ETIMEDOUT:
        return true;
    default:
        return false;
    }
}

std::string fileDigest(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open for reading");
    std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), XXH3_freeState);
    XXH3_128bits_reset(state.get());
    std::vector<char> buf(1 << 20);
    while (in) {
        in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
        XXH3_128bits_update(state.get(), buf.data(), static_cast<std::size_t>(in.gcount()));
    }
    return hex128(XXH3_128bits_digest(state.get()));
}

std::string stringDigest(const std::string& text)
{
    return hex128(XXH3_128bits(text.data(), text.size()));
}

void writeJson(const std::string& path, const nlohmann::json& j)
{
    writeAtomically(path, [&](const std::string& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out << j.dump(2) << "\n";
        if (!out.flush()) throw InputError(path + ": cannot write");
    });
}

nlohmann::json readJson(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open for reading");
    nlohmann::json j = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) throw InputError(path + ": not valid JSON");
    return j;
}

namespace {

/// OpenVDB stamps every file with a random UUID (36 characters at byte 21 of the header), so
/// two writes of the same grids differ. We replace it by a UUID derived from the rest of the
/// file, which makes .vdb artifacts byte-identical for identical content: their digests then
/// identify content, as the cache and the reproducibility checks need.
void makeVdbUuidDeterministic(const std::string& path)
{
    constexpr std::size_t UUID_OFFSET = 21, UUID_LENGTH = 36, HEAD = UUID_OFFSET + UUID_LENGTH;
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "r+b"), std::fclose);
    if (!f) throw InputError(path + ": cannot open for reading: " + std::strerror(errno));
    // The rest of the file hashed in chunks (a ct.vdb is ~200 MB: never held whole).
    std::vector<char> buf(std::size_t(4) << 20);
    std::size_t n = std::fread(buf.data(), 1, buf.size(), f.get());
    const bool isVdb = n > HEAD && buf[0] == 0x20 && buf[1] == 0x42 && buf[2] == 0x44 && buf[3] == 0x56 &&
                       buf[UUID_OFFSET + 8] == '-';
    if (!isVdb) throw InputError(path + ": unexpected OpenVDB file header");
    std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), XXH3_freeState);
    XXH3_128bits_reset(state.get());
    XXH3_128bits_update(state.get(), buf.data() + HEAD, n - HEAD);
    while ((n = std::fread(buf.data(), 1, buf.size(), f.get())) > 0) XXH3_128bits_update(state.get(), buf.data(), n);
    if (std::ferror(f.get())) throw InputError(path + ": cannot read: " + std::strerror(errno));
    const XXH128_hash_t h = XXH3_128bits_digest(state.get());
    char hex[33];
    std::snprintf(hex, sizeof hex, "%016llx%016llx", static_cast<unsigned long long>(h.high64),
                  static_cast<unsigned long long>(h.low64));
    const std::string s(hex);
    const std::string uuid = s.substr(0, 8) + "-" + s.substr(8, 4) + "-" + s.substr(12, 4) + "-" +
                             s.substr(16, 4) + "-" + s.substr(20, 12);
    if (std::fseek(f.get(), static_cast<long>(UUID_OFFSET), SEEK_SET) != 0 ||
        std::fwrite(uuid.data(), 1, uuid.size(), f.get()) != uuid.size() || std::fflush(f.get()) != 0)
        throw InputError(path + ": cannot write");
}

} // namespace

void writeGrids(const std::string& path, const openvdb::GridPtrVec& grids)
{
    writeGrids(path, grids, VdbValues::Blosc);
}

namespace {

/// An output stream buffer on a file descriptor that buffers every write, however large, in
/// 1 MB (std::filebuf hands any write of 1 KB or more to the kernel at once) and seeks.
class FileWriteBuffer : public std::streambuf {
public:
    explicit FileWriteBuffer(int fd) : mFd(fd), mBuffer(std::size_t(1) << 20) { resetPut(); }
    /// The errno of the first failed write or seek; 0 when none failed.
    int error() const { return mError; }

protected:
    int_type overflow(int_type ch) override
    {
        if (!drain()) return traits_type::eof();
        if (!traits_type::eq_int_type(ch, traits_type::eof())) {
            *pptr() = traits_type::to_char_type(ch);
            pbump(1);
        }
        return traits_type::not_eof(ch);
    }
    std::streamsize xsputn(const char* s, std::streamsize n) override
    {
        std::streamsize done = 0;
        while (done < n) {
            if (pptr() == epptr() && !drain()) break;
            const std::streamsize k = std::min<std::streamsize>(epptr() - pptr(), n - done);
            std::memcpy(pptr(), s + done, std::size_t(k));
            pbump(int(k));
            done += k;
        }
        return done;
    }
    int sync() override { return drain() ? 0 : -1; }
    pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode which) override
    {
        if (!(which & std::ios_base::out)) return pos_type(off_type(-1));
        if (off == 0 && dir == std::ios_base::cur) return pos_type(mFileOffset + (pptr() - pbase()));
        if (!drain()) return pos_type(off_type(-1));
        const int whence = dir == std::ios_base::beg ? SEEK_SET : dir == std::ios_base::cur ? SEEK_CUR : SEEK_END;
        const off_t at = ::lseek(mFd, off_t(off), whence);
        if (at < 0) {
            mError = mError ? mError : errno;
            return pos_type(off_type(-1));
        }
        mFileOffset = at;
        return pos_type(off_type(at));
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override
    {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }

private:
    void resetPut() { setp(mBuffer.data(), mBuffer.data() + mBuffer.size()); }
    bool drain()
    {
        const std::size_t n = std::size_t(pptr() - pbase());
        if (const int error = writeFully(mFd, pbase(), n)) {
            mError = mError ? mError : error;
            return false;
        }
        mFileOffset += off_t(n);
        resetPut();
        return true;
    }

    int mFd;
    off_t mFileOffset = 0;
    int mError = 0;
    std::vector<char> mBuffer;
};

/// Writes what openvdb::io::File::write writes (a seekable archive: the same bytes) through a
/// FileWriteBuffer. io::File's own std::ofstream makes a write() per leaf (2 KB of a float
/// leaf): for ct.vdb of the full phantom (224 MB) 0.26 s of system CPU on the way to the first
/// pair, against ~0.05 s in 1 MB writes while the kernel's memory is not fragmented (README,
/// "Where ingest's time goes": with a fragmented page cache both cost about the same).
class BufferedVdbWriter : public openvdb::io::Archive {
public:
    void write(const std::string& path, const openvdb::GridPtrVec& grids) const
    {
        const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
        if (fd < 0) throw std::system_error(errno, std::generic_category(), path + ": cannot open for writing");
        int error = 0;
        {
            FileWriteBuffer buffer(fd);
            std::ostream out(&buffer);
            try {
                Archive::write(out, grids, /*seekable=*/true);
                out.flush();
            } catch (...) {
                ::close(fd);
                throw;
            }
            error = buffer.error();
            if (!error && !out) error = EIO;
        }
        if (::close(fd) != 0 && !error) error = errno;
        if (error) throw std::system_error(error, std::generic_category(), path + ": cannot write");
    }
};

} // namespace

void writeVdbFile(const std::string& file, const openvdb::GridPtrVec& grids, VdbValues values)
{
    BufferedVdbWriter writer;
    uint32_t compression = openvdb::io::COMPRESS_ACTIVE_MASK;
    if (values == VdbValues::Blosc)
        compression |= openvdb::io::Archive::hasBloscCompression() ? openvdb::io::COMPRESS_BLOSC
                                                                   : openvdb::io::COMPRESS_ZIP;
    writer.setCompression(compression);
    writer.write(file, grids);
}

void writeGrids(const std::string& path, const openvdb::GridPtrVec& grids, VdbValues values)
{
    writeAtomically(path, [&](const std::string& tmp) {
        writeVdbFile(tmp, grids, values);
        makeVdbUuidDeterministic(tmp);
    });
}

namespace {

openvdb::GridBase::Ptr readGridLoading(const std::string& path, const std::string& gridName, bool delayLoad)
{
    try {
        openvdb::io::File file(path);
        file.open(delayLoad);
        if (!file.hasGrid(gridName)) {
            file.close();
            throw InputError(path + ": has no grid named '" + gridName + "'");
        }
        openvdb::GridBase::Ptr grid = file.readGrid(gridName);
        file.close();
        return grid;
    } catch (const openvdb::Exception& e) {
        throw InputError(path + ": cannot read VDB: " + e.what());
    }
}

} // namespace

openvdb::GridBase::Ptr readGrid(const std::string& path, const std::string& gridName)
{
    return readGridLoading(path, gridName, false);
}

openvdb::GridBase::Ptr readGridDelayed(const std::string& path, const std::string& gridName)
{
    return readGridLoading(path, gridName, true);
}

namespace {

bool littleEndianHost()
{
    const uint16_t probe = 1;
    uint8_t firstByte = 0;
    std::memcpy(&firstByte, &probe, 1);
    return firstByte == 1;
}

/// Writes `n` bytes to `file` (created or truncated) in one call. @throw InputError naming it.
void writeBytes(const std::string& file, const void* data, std::size_t n)
{
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(file.c_str(), "wb"), std::fclose);
    if (!f) throw InputError(file + ": cannot open for writing: " + std::strerror(errno));
    if (std::fwrite(data, 1, n, f.get()) != n || std::fflush(f.get()) != 0)
        throw InputError(file + ": cannot write: " + std::strerror(errno));
}

/// The bytes OpenMesh's binary PLY writer makes of a triangle mesh without deleted elements
/// (the header, x y z per vertex in index order, then per face the count 3 and the vertex
/// indices in its face-vertex circulation order), built in memory and written at once instead
/// of one stream write per value (the full phantom's 16.7 MB: ~4.8 M writes). Returns false
/// for any other mesh (it then goes through OpenMesh).
bool writeTrianglePly(const std::string& tmp, const TriMesh& mesh)
{
    if (!littleEndianHost()) return false;
    const std::size_t nv = mesh.n_vertices(), nf = mesh.n_faces();
    if (mesh.has_vertex_status())
        for (std::size_t v = 0; v < nv; ++v)
            if (mesh.status(OpenMesh::VertexHandle(int(v))).deleted()) return false;
    if (mesh.has_face_status())
        for (std::size_t f = 0; f < nf; ++f)
            if (mesh.status(OpenMesh::FaceHandle(int(f))).deleted()) return false;
    const std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(nv) +
                               "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                               std::to_string(nf) + "\nproperty list uchar int vertex_indices\nend_header\n";
    std::vector<char> bytes(header.size() + nv * 12 + nf * 13);
    char* out = bytes.data();
    std::memcpy(out, header.data(), header.size());
    out += header.size();
    for (std::size_t v = 0; v < nv; ++v, out += 12) {
        const TriMesh::Point& p = mesh.point(OpenMesh::VertexHandle(int(v)));
        const float xyz[3] = {p[0], p[1], p[2]};
        std::memcpy(out, xyz, 12);
    }
    for (std::size_t f = 0; f < nf; ++f, out += 13) {
        int32_t idx[3];
        int n = 0;
        for (auto it = mesh.cfv_iter(OpenMesh::FaceHandle(int(f))); it.is_valid(); ++it) {
            if (n == 3) return false;  // not a triangle
            idx[n++] = it->idx();
        }
        if (n != 3) return false;
        out[0] = char(3);
        std::memcpy(out + 1, idx, sizeof idx);
    }
    writeBytes(tmp, bytes.data(), bytes.size());
    return true;
}

} // namespace

void writeMesh(const std::string& path, const TriMesh& mesh)
{
    writeAtomically(path, [&](const std::string& tmp) {
        if (writeTrianglePly(tmp, mesh)) return;
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

namespace {

void appendU32(std::string& out, uint32_t v)
{
    for (int shift = 24; shift >= 0; shift -= 8) out.push_back(static_cast<char>(v >> shift));
}

/// One PNG chunk: length, type, data, and the CRC-32 of type and data.
void appendChunk(std::string& out, const char* type, const void* data, std::size_t n)
{
    appendU32(out, static_cast<uint32_t>(n));
    const std::size_t typeAt = out.size();
    out.append(type, 4);
    if (n) out.append(static_cast<const char*>(data), n);
    // ISA-L's CRC-32 of gzip, the same polynomial and reflection as PNG's (zlib's crc32).
    appendU32(out, crc32_gzip_refl(0, reinterpret_cast<const unsigned char*>(out.data() + typeAt), 4 + n));
}

/// PNG bytes of 8-bit pixels, `channels` 1 (gray) or 3 (RGB) per pixel, top row first.
std::string encodePngPixels(int width, int height, int channels, const uint8_t* pixels)
{
    if (width <= 0 || height <= 0) throw InputError("encodePng: empty image");
    if (static_cast<std::size_t>(width) * std::size_t(channels) + 1 >
        (std::size_t(1) << 30) / static_cast<std::size_t>(height))
        throw InputError("encodePng: " + std::to_string(width) + " x " + std::to_string(height) +
                         " px is too large for one image");
    // Frames are many: favour speed. Every row filtered with Up (the difference to the row
    // above, which the fly-over's smooth shading makes mostly small), deflated by ISA-L at
    // level 1 into one zlib stream: about 4x faster than zlib's run-length deflate at level 3,
    // the files ~15% larger; the pixels are the same.
    const std::size_t rowBytes = static_cast<std::size_t>(width) * std::size_t(channels);
    const std::size_t rows = static_cast<std::size_t>(height);
    thread_local std::vector<unsigned char> filtered, deflated, levelBuffer;
    filtered.resize((rowBytes + 1) * rows);
    for (std::size_t y = 0; y < rows; ++y) {
        unsigned char* out = filtered.data() + y * (rowBytes + 1);
        const unsigned char* row = pixels + y * rowBytes;
        out[0] = 2;  // filter type Up (the first row's "above" is zero)
        if (y == 0) {
            std::memcpy(out + 1, row, rowBytes);
        } else {
            const unsigned char* above = row - rowBytes;
            for (std::size_t i = 0; i < rowBytes; ++i) out[1 + i] = static_cast<unsigned char>(row[i] - above[i]);
        }
    }
    levelBuffer.resize(ISAL_DEF_LVL1_DEFAULT);
    // Stored blocks bound the output: the input plus 5 bytes per 64 KiB, the zlib header and
    // its Adler-32; grown below should ISA-L ever need more.
    deflated.resize(filtered.size() + filtered.size() / 8 + 1024);
    isal_zstream z;
    isal_deflate_init(&z);
    z.level = 1;
    z.level_buf = levelBuffer.data();
    z.level_buf_size = static_cast<uint32_t>(levelBuffer.size());
    z.gzip_flag = IGZIP_ZLIB;
    z.end_of_stream = 1;
    z.flush = NO_FLUSH;
    z.next_in = filtered.data();
    z.avail_in = static_cast<uint32_t>(filtered.size());
    z.next_out = deflated.data();
    z.avail_out = static_cast<uint32_t>(deflated.size());
    while (z.internal_state.state != ZSTATE_END) {
        if (z.avail_out == 0) {
            const std::size_t used = deflated.size();
            deflated.resize(2 * used);
            z.next_out = deflated.data() + used;
            z.avail_out = static_cast<uint32_t>(deflated.size() - used);
        }
        const int rc = isal_deflate(&z);
        if (rc != COMP_OK) throw std::runtime_error("encodePng: ISA-L deflate failed (" + std::to_string(rc) + ")");
    }
    const std::size_t idatBytes = static_cast<std::size_t>(z.total_out);

    std::string png("\x89PNG\r\n\x1a\n", 8);
    png.reserve(idatBytes + 64);
    std::string ihdr;
    appendU32(ihdr, static_cast<uint32_t>(width));
    appendU32(ihdr, static_cast<uint32_t>(height));
    const char colourType = channels == 3 ? 2 : 0;  // RGB or gray
    ihdr += {8, colourType, 0, 0, 0};  // 8 bits, deflate, filter method 0, no interlace
    appendChunk(png, "IHDR", ihdr.data(), ihdr.size());
    appendChunk(png, "IDAT", deflated.data(), idatBytes);
    appendChunk(png, "IEND", nullptr, 0);
    return png;
}

} // namespace

std::string encodePng(const RgbImage& image)
{
    if (image.rgb.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 3)
        throw InputError("encodePng: the buffer does not match the image size");
    return encodePngPixels(image.width, image.height, 3, image.rgb.data());
}

std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray)
{
    if (width <= 0 || height <= 0 || gray.size() != std::size_t(width) * std::size_t(height))
        throw InputError("encodeGrayPng: the buffer does not match the image size");
    return encodePngPixels(width, height, 1, gray.data());
}

void writePng(const std::string& path, const RgbImage& image)
{
    std::string png;
    try {
        png = encodePng(image);
    } catch (const InputError& e) {
        throw InputError(path + ": " + e.what());
    }
    writeAtomically(path, [&](const std::string& tmp) { writeBytes(tmp, png.data(), png.size()); });
}

namespace {

uint32_t readU32(const unsigned char* p)
{
    return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | uint32_t(p[3]);
}

/// Reverses PNG filtering (filter method 0, types 0-4) of `rows` rows of `rowBytes` bytes
/// with `bpp` bytes per pixel, each preceded by its filter type byte, into `out`.
/// @return false for an unknown filter type
bool unfilterRows(const unsigned char* in, std::size_t rowBytes, std::size_t rows, std::size_t bpp, uint8_t* out)
{
    for (std::size_t y = 0; y < rows; ++y) {
        const unsigned char* src = in + y * (rowBytes + 1);
        uint8_t* row = out + y * rowBytes;
        const uint8_t* above = y > 0 ? row - rowBytes : nullptr;
        const unsigned char type = src[0];
        ++src;
        switch (type) {
        case 0:
            std::memcpy(row, src, rowBytes);
            break;
        case 1:
            for (std::size_t i = 0; i < rowBytes; ++i)
                row[i] = uint8_t(src[i] + (i >= bpp ? row[i - bpp] : 0));
            break;
        case 2:
            if (!above) std::memcpy(row, src, rowBytes);
            else
                for (std::size_t i = 0; i < rowBytes; ++i) row[i] = uint8_t(src[i] + above[i]);
            break;
        case 3:
            for (std::size_t i = 0; i < rowBytes; ++i) {
                const unsigned left = i >= bpp ? row[i - bpp] : 0, up = above ? above[i] : 0;
                row[i] = uint8_t(src[i] + ((left + up) >> 1));
            }
            break;
        case 4:
            for (std::size_t i = 0; i < rowBytes; ++i) {
                const int a = i >= bpp ? row[i - bpp] : 0, b = above ? above[i] : 0,
                          c = (above && i >= bpp) ? above[i - bpp] : 0;
                const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
                const int predictor = (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
                row[i] = uint8_t(src[i] + predictor);
            }
            break;
        default:
            return false;
        }
    }
    return true;
}

} // namespace

// A file with any chunk that could make libpng's simplified reader (PNG_FORMAT_RGB) return
// other values than the stored ones (gamma, colour space, transparency, palette) is declined.
bool decodePlainRgbPng(const std::string& bytes, RgbImage& out)
{
    const auto* p = reinterpret_cast<const unsigned char*>(bytes.data());
    const std::size_t size = bytes.size();
    if (size < 8 + 25 || std::memcmp(p, "\x89PNG\r\n\x1a\n", 8) != 0) return false;
    std::size_t at = 8;
    uint32_t width = 0, height = 0;
    std::vector<std::pair<const unsigned char*, std::size_t>> idat;
    bool ended = false, idatClosed = false;
    while (!ended) {
        if (size - at < 12) return false;
        const std::size_t length = readU32(p + at);
        const unsigned char* type = p + at + 4;
        if (length > size - at - 12) return false;
        const unsigned char* data = type + 4;
        const bool critical = (type[0] & 0x20) == 0;
        if (critical && crc32_gzip_refl(0, type, 4 + length) != readU32(data + length)) return false;
        const std::string name(reinterpret_cast<const char*>(type), 4);
        if (at == 8) {
            if (name != "IHDR" || length != 13) return false;
            width = readU32(data);
            height = readU32(data + 4);
            // 8 bits, RGB, deflate, filter method 0, no interlace; libpng's default size limit.
            if (data[8] != 8 || data[9] != 2 || data[10] != 0 || data[11] != 0 || data[12] != 0) return false;
            if (width == 0 || height == 0 || width > 1000000u || height > 1000000u) return false;
        } else if (name == "IDAT") {
            if (idatClosed) return false;
            idat.emplace_back(data, length);
        } else {
            if (!idat.empty()) idatClosed = true;
            if (name == "IEND") ended = true;
            else if (name != "tEXt" && name != "zTXt" && name != "iTXt" && name != "tIME" && name != "pHYs")
                return false;
        }
        at += 12 + length;
    }
    const std::size_t rowBytes = std::size_t(width) * 3;
    if ((rowBytes + 1) > (std::size_t(1) << 31) / std::size_t(height)) return false;
    thread_local std::vector<unsigned char> filtered;
    filtered.resize((rowBytes + 1) * std::size_t(height));
    inflate_state s;
    isal_inflate_init(&s);
    s.crc_flag = ISAL_ZLIB;
    s.next_out = filtered.data();
    s.avail_out = static_cast<uint32_t>(filtered.size());
    for (std::size_t k = 0; k < idat.size(); ++k) {
        s.next_in = const_cast<uint8_t*>(idat[k].first);
        s.avail_in = static_cast<uint32_t>(idat[k].second);
        while (s.avail_in > 0 && s.block_state != ISAL_BLOCK_FINISH) {
            const uint32_t inBefore = s.avail_in, outBefore = s.avail_out;
            if (isal_inflate(&s) != ISAL_DECOMP_OK) return false;
            if (s.avail_in == inBefore && s.avail_out == outBefore) return false;  // no progress
        }
        // Data after the end of the zlib stream: left to libpng's rules.
        if (s.block_state == ISAL_BLOCK_FINISH && (s.avail_in > 0 || k + 1 < idat.size())) return false;
    }
    if (s.block_state != ISAL_BLOCK_FINISH || s.avail_out != 0) return false;
    out.width = int(width);
    out.height = int(height);
    out.rgb.resize(rowBytes * std::size_t(height));
    return unfilterRows(filtered.data(), rowBytes, std::size_t(height), 3, out.rgb.data());
}

RgbImage readPng(const std::string& path)
{
    // The file is read once: decoded here when plain, else given to libpng from memory.
    std::ifstream in(path, std::ios::binary | std::ios::ate);
    if (!in) throw InputError(path + ": cannot open for reading");
    std::string bytes(static_cast<std::size_t>(std::max<std::streamoff>(0, in.tellg())), '\0');
    in.seekg(0);
    if (!in.read(bytes.data(), static_cast<std::streamsize>(bytes.size())))
        throw InputError(path + ": cannot read");
    RgbImage out;
    if (decodePlainRgbPng(bytes, out)) return out;
    png_image img{};
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&img, bytes.data(), bytes.size()))
        throw InputError(path + ": cannot read PNG: " + img.message);
    img.format = PNG_FORMAT_RGB;
    out.width = static_cast<int>(img.width);
    out.height = static_cast<int>(img.height);
    out.rgb.resize(PNG_IMAGE_SIZE(img));
    if (!png_image_finish_read(&img, nullptr, out.rgb.data(), 0, nullptr))
        throw InputError(path + ": cannot read PNG: " + img.message);
    return out;
}

nlohmann::json centerlineToJson(const Centerline& c)
{
    using nlohmann::json;
    json pos = json::array(), tan = json::array(), nor = json::array(), rad = json::array(),
         bridged = json::array();
    auto v3 = [](const Vec3d& v) { return json::array({v.x, v.y, v.z}); };
    for (const auto& p : c.points) {
        pos.push_back(v3(p.positionMm));
        tan.push_back(v3(p.tangent));
        nor.push_back(v3(p.normal));
        rad.push_back(p.radiusMm);
        bridged.push_back(p.bridged);
    }
    json out{{"schema", "flyover.centerline/1"},
             {"world_frame", WORLD_FRAME},
             {"units", "mm"},
             {"order", "rectum to cecum"},
             {"step_mm", c.stepMm},
             {"length_mm", c.lengthMm()},
             {"point_count", c.points.size()},
             {"position_mm", pos},
             {"tangent", tan},
             {"normal", nor},
             {"radius_mm", rad},
             {"bridged", bridged}};
    if (!c.leftOutBranchMm.empty()) {  // only then: other files stay byte for byte
        json axis = json::array();
        for (const Vec3d& p : c.leftOutBranchMm) axis.push_back(v3(p));
        out["left_out_branch"] = json{{"meaning", "a narrow tube at the lumen's far end that the path leaves out "
                                                  "(the terminal ileum off the cecum): its axis past the mouth and "
                                                  "its radius; its wall is not counted in coverage"},
                                      {"axis_mm", axis},
                                      {"radius_mm", c.leftOutBranchRadiusMm}};
    }
    if (!c.segment.empty()) {  // only on a labelled path (colon/anatomy_segments.h)
        out["segment"] = c.segment;
        json landmarks = json::object();
        for (const CenterlineLandmark& l : c.landmarks)
            landmarks[l.name] = json{{"index", l.index}, {"arc_mm", l.arcMm}, {"position_mm", v3(l.positionMm)}};
        out["landmarks"] = landmarks;
        out["segments_frame"] = c.segmentsFrame;
        if (!c.segmentsFrameReason.empty()) out["segments_frame_reason"] = c.segmentsFrameReason;
    }
    return out;
}

Centerline centerlineFromJson(const nlohmann::json& j, const std::string& source)
{
    auto fail = [&](const std::string& what) -> void { throw InputError(source + ": " + what); };
    if (!j.is_object() || j.value("schema", "") != "flyover.centerline/1")
        fail("not a flyover centerline (schema flyover.centerline/1)");
    if (j.value("world_frame", "") != WORLD_FRAME) fail("centerline world frame is not LPS");
    Centerline c;
    c.stepMm = j.value("step_mm", 1.0);
    const auto& pos = j.at("position_mm");
    const auto& tan = j.at("tangent");
    const auto& nor = j.at("normal");
    const auto& rad = j.at("radius_mm");
    const auto& br = j.at("bridged");
    const std::size_t n = pos.size();
    if (tan.size() != n || nor.size() != n || rad.size() != n || br.size() != n)
        fail("centerline arrays differ in length");
    auto v3 = [&](const nlohmann::json& a) {
        if (!a.is_array() || a.size() != 3) fail("expected [x,y,z]");
        return Vec3d{a[0].get<double>(), a[1].get<double>(), a[2].get<double>()};
    };
    c.points.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        c.points[i].positionMm = v3(pos[i]);
        c.points[i].tangent = v3(tan[i]);
        c.points[i].normal = v3(nor[i]);
        c.points[i].radiusMm = rad[i].get<double>();
        c.points[i].bridged = br[i].get<bool>();
    }
    if (j.contains("left_out_branch")) {
        const auto& b = j.at("left_out_branch");
        if (!b.is_object() || !b.contains("axis_mm") || !b.at("axis_mm").is_array())
            fail("left_out_branch: expected an object with axis_mm");
        for (const auto& a : b.at("axis_mm")) c.leftOutBranchMm.push_back(v3(a));
        c.leftOutBranchRadiusMm = b.value("radius_mm", 0.0);
        if (!(c.leftOutBranchRadiusMm >= 0) || !std::isfinite(c.leftOutBranchRadiusMm))
            fail("left_out_branch: radius_mm must be a finite value >= 0");
    }
    // Anatomical segments: optional (files written before them load without).
    if (j.contains("segment")) {
        const auto& seg = j.at("segment");
        if (!seg.is_array() || seg.size() != n) fail("segment: expected one string per point");
        for (const auto& s : seg) {
            if (!s.is_string()) fail("segment: expected one string per point");
            c.segment.push_back(s.get<std::string>());
        }
        c.segmentsFrame = j.value("segments_frame", "");
        c.segmentsFrameReason = j.value("segments_frame_reason", "");
    }
    if (j.contains("landmarks")) {
        const auto& lm = j.at("landmarks");
        if (!lm.is_object()) fail("landmarks: expected an object");
        for (auto it = lm.begin(); it != lm.end(); ++it) {
            const auto& l = it.value();
            if (!l.is_object() || !l.contains("index") || !l.at("index").is_number_unsigned() ||
                l.at("index").get<std::size_t>() >= n)
                fail("landmarks: " + it.key() + ": expected an index of a point");
            CenterlineLandmark m;
            m.name = it.key();
            m.index = l.at("index").get<std::size_t>();
            m.arcMm = l.value("arc_mm", double(m.index) * c.stepMm);
            m.positionMm = l.contains("position_mm") ? v3(l.at("position_mm")) : c.points[m.index].positionMm;
            c.landmarks.push_back(m);
        }
        // Path order, as written (a JSON object's keys come back sorted).
        std::stable_sort(c.landmarks.begin(), c.landmarks.end(),
                         [](const CenterlineLandmark& a, const CenterlineLandmark& b) { return a.index < b.index; });
    }
    return c;
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
