#include "pipeline/vdb_io.h"

#include "pipeline/atomic_write.h"
#include "pipeline/grid_write.h"
#include "volume/error.h"
#include "volume/fd_write.h"

#include <xxhash.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fcntl.h>
#include <fstream>
#include <memory>
#include <unistd.h>
#include <vector>

namespace flyover {

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

} // namespace flyover
