// gzip inflation by ISA-L, read in order: see gzip_stream.h.

#include "volume/io/gzip_stream.h"

#include <isa-l/igzip_lib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <vector>

#include <fcntl.h>
#include <unistd.h>

namespace flyover::imageio {

namespace {

/// Compressed bytes read from the file at a time.
constexpr std::size_t INPUT_BYTES = std::size_t(1) << 20;

/// ISA-L's inflate results in words (zlib's wording where zlib has one).
const char* inflateProblem(int rc)
{
    switch (rc) {
    case ISAL_INVALID_BLOCK: return "invalid deflate block";
    case ISAL_INVALID_SYMBOL: return "invalid deflate code";
    case ISAL_INVALID_LOOKBACK: return "invalid distance too far back";
    case ISAL_INVALID_WRAPPER: return "incorrect gzip header";
    case ISAL_UNSUPPORTED_METHOD: return "unknown compression method";
    case ISAL_INCORRECT_CHECKSUM: return "incorrect data check: the CRC-32 or length in a trailer does not match";
    case ISAL_NEED_DICT: return "the stream needs a preset dictionary";
    default: return "inflate error";
    }
}

} // namespace

struct GzipStream::State {
    inflate_state inflate{};
    std::vector<uint8_t> input = std::vector<uint8_t>(INPUT_BYTES);
    std::size_t begin = 0, end = 0;  ///< unread input: [begin, end) of `input` (direct mode)
};

GzipStream::GzipStream(const std::string& path) : mState(std::make_unique<State>())
{
    mFd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (mFd < 0) {
        mError = "cannot open " + path + ": " + std::strerror(errno);
        return;
    }
    ::posix_fadvise(mFd, 0, 0, POSIX_FADV_SEQUENTIAL);
}

GzipStream::~GzipStream()
{
    if (mFd >= 0) ::close(mFd);
}

void GzipStream::fail(const std::string& why)
{
    mError = "gzip data is truncated or corrupt after " + std::to_string(mPosition) + " decompressed bytes (" + why +
             ")";
}

bool GzipStream::refill()
{
    State& s = *mState;
    // Unread input: in direct mode [begin, end); when inflating, what ISA-L has not taken.
    std::size_t keep, from;
    if (mDirect || !mStarted) {
        from = s.begin;
        keep = s.end - s.begin;
    } else {
        keep = s.inflate.avail_in;
        from = keep ? static_cast<std::size_t>(s.inflate.next_in - s.input.data()) : 0;
    }
    if (keep && from) std::memmove(s.input.data(), s.input.data() + from, keep);
    std::size_t have = keep;
    bool grew = false;
    while (!mEof && have < s.input.size()) {
        const ssize_t got = ::read(mFd, s.input.data() + have, s.input.size() - have);
        if (got < 0 && errno == EINTR) continue;
        if (got < 0) {
            mError = std::string("cannot read the compressed data: ") + std::strerror(errno);
            mEof = true;
            break;
        }
        if (got == 0) {
            mEof = true;
            break;
        }
        have += static_cast<std::size_t>(got);
        grew = true;
        break;  // one read at a time: inflate what came
    }
    s.begin = 0;
    s.end = have;
    s.inflate.next_in = s.input.data();
    s.inflate.avail_in = static_cast<uint32_t>(have);
    return grew;
}

std::size_t GzipStream::read(char* out, std::size_t n)
{
    if (!mError.empty() || mEnd || n == 0) return 0;
    State& s = *mState;
    if (!mStarted) {
        // gzread's choice: gzip when the file starts with the magic bytes, else the file as it is.
        while (s.end < 2 && !mEof && mError.empty()) refill();
        if (!mError.empty()) return 0;
        mDirect = !(s.end >= 2 && s.input[0] == 0x1f && s.input[1] == 0x8b);
        mStarted = true;
        if (!mDirect) {
            isal_inflate_init(&s.inflate);
            s.inflate.crc_flag = ISAL_GZIP;
            s.inflate.next_in = s.input.data();
            s.inflate.avail_in = static_cast<uint32_t>(s.end);
        }
    }
    std::size_t done = 0;
    if (mDirect) {
        while (done < n) {
            if (s.begin == s.end) {
                if (mEof || !refill()) break;
                continue;
            }
            const std::size_t take = std::min(n - done, s.end - s.begin);
            std::memcpy(out + done, s.input.data() + s.begin, take);
            s.begin += take;
            done += take;
        }
        mPosition += done;
        if (done < n && mError.empty()) mEnd = true;
        return done;
    }
    while (done < n) {
        if (mMemberDone) {
            // Another member follows when the next bytes are the gzip magic; anything else
            // (or nothing) ends the data, as in gzread.
            while (s.inflate.avail_in < 2 && !mEof && mError.empty()) refill();
            if (!mError.empty()) break;
            if (s.inflate.avail_in < 2 || s.inflate.next_in[0] != 0x1f || s.inflate.next_in[1] != 0x8b) {
                mEnd = true;
                break;
            }
            uint8_t* next = s.inflate.next_in;
            const uint32_t avail = s.inflate.avail_in;
            isal_inflate_reset(&s.inflate);
            s.inflate.crc_flag = ISAL_GZIP;
            s.inflate.next_in = next;
            s.inflate.avail_in = avail;
            mMemberDone = false;
        }
        if (s.inflate.avail_in == 0 && !mEof) {
            refill();
            if (!mError.empty()) break;
        }
        const uint32_t room =
            static_cast<uint32_t>(std::min<std::size_t>(n - done, std::numeric_limits<uint32_t>::max()));
        s.inflate.next_out = reinterpret_cast<uint8_t*>(out + done);
        s.inflate.avail_out = room;
        const uint32_t inBefore = s.inflate.avail_in;
        const int rc = isal_inflate(&s.inflate);
        const std::size_t produced = room - s.inflate.avail_out;
        done += produced;
        mPosition += produced;
        if (rc < 0) {
            fail(inflateProblem(rc));
            break;
        }
        if (s.inflate.block_state == ISAL_BLOCK_FINISH) {
            mMemberDone = true;
            continue;
        }
        if (produced == 0 && s.inflate.avail_in == inBefore) {
            // Nothing taken and nothing given: ISA-L needs input that the file no longer has.
            if (mEof) {
                fail("unexpected end of file");
                break;
            }
            if (!refill()) {
                if (mError.empty()) fail(mEof ? "unexpected end of file" : "inflate made no progress");
                break;
            }
        }
    }
    return done;
}

bool GzipStream::readToEnd()
{
    std::vector<char> scratch(std::size_t(1) << 20);
    while (mError.empty() && !mEnd) read(scratch.data(), scratch.size());
    return mError.empty();
}

} // namespace flyover::imageio
