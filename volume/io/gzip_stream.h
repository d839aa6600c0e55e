/// @file gzip_stream.h
/// @brief A gzip file's decompressed bytes, read in order and inflated by ISA-L's igzip
///        (Intel's Intelligent Storage Acceleration Library: about 1.9x zlib's inflate on a
///        CT, streamed, so a few MB are held whatever the file's size). Internal to volume/.
///
/// It reads what zlib's gzread reads: concatenated members one after the other (bytes after
/// a member that do not start another are ignored, as gzread ignores trailing garbage); a
/// file that does not start with the gzip magic bytes as it is. Every member's CRC-32 and
/// length (its trailer) are checked; truncated and corrupt data are reported in words.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace flyover::imageio {

class GzipStream {
public:
    /// Opens `path`; a problem opening it is kept for error(), not thrown.
    explicit GzipStream(const std::string& path);
    ~GzipStream();
    GzipStream(const GzipStream&) = delete;
    GzipStream& operator=(const GzipStream&) = delete;

    /// Reads up to `n` decompressed bytes into `out`; returns how many. Fewer than `n` only at
    /// the end of the data or on a problem (then error() says which).
    std::size_t read(char* out, std::size_t n);

    /// Reads on to the end of the data (discarding it), so that the trailer of the member
    /// holding the last bytes read is checked too. False on a problem (error()).
    bool readToEnd();

    /// "" or the problem, naming no file but `path` in "cannot open PATH: ...": "cannot read the
    /// compressed data: ...", or "gzip data is truncated or corrupt after N decompressed bytes
    /// (WHY)".
    const std::string& error() const { return mError; }

    /// Decompressed bytes delivered so far.
    uint64_t position() const { return mPosition; }

private:
    /// Moves the unread input to the front of the buffer and reads more after it; false at the
    /// end of the file (or on a read error, then mError is set).
    bool refill();
    void fail(const std::string& why);

    struct State;
    std::unique_ptr<State> mState;
    int mFd = -1;
    bool mEof = false;       ///< the file has no more bytes to read
    bool mStarted = false;   ///< the first bytes were looked at (gzip or not)
    bool mDirect = false;    ///< no gzip magic: the file's bytes as they are
    bool mMemberDone = false;
    bool mEnd = false;       ///< no more data
    uint64_t mPosition = 0;
    std::string mError;
};

} // namespace flyover::imageio
