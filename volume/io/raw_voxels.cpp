// NIfTI voxels read by slices, inflated while read: see raw_voxels.h.

#include "volume/io/raw_voxels.h"

#include "volume/error.h"
#include "volume/io/gzip_stream.h"
#include "volume/io/io_util.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include <fcntl.h>
#include <unistd.h>

namespace flyover::imageio {

namespace {

/// Float bytes per block, and blocks the producer may run ahead of the consumer: a few MB,
/// enough to keep it busy while the consumer resamples a slab.
constexpr std::size_t BLOCK_BYTES = std::size_t(4) << 20;
constexpr std::size_t BLOCKS_AHEAD = 6;

/// Reads bytes from the data file, sequentially from a start position.
class ByteReader {
public:
    ByteReader(const std::string& name, const RawLayout& layout) : mName(name), mLayout(layout)
    {
        if (layout.compressed) {
            mGz = std::make_unique<GzipStream>(layout.dataPath);
            mError = mGz->error();
        } else {
            mFd = ::open(layout.dataPath.c_str(), O_RDONLY | O_CLOEXEC);
            if (mFd < 0) mError = "cannot open " + layout.dataPath + ": " + std::strerror(errno);
        }
    }
    ~ByteReader()
    {
        if (mFd >= 0) ::close(mFd);
    }
    ByteReader(const ByteReader&) = delete;
    ByteReader& operator=(const ByteReader&) = delete;

    /// Moves forward to decompressed byte `pos` (never backwards). "" or the problem.
    std::string skipTo(uint64_t pos)
    {
        if (!mError.empty()) return mError;
        if (!mGz) {
            mPos = pos;
            return "";
        }
        std::vector<char> scratch(std::min<uint64_t>(pos - mPos, uint64_t(1) << 20) + 1);
        while (mPos < pos) {
            const std::size_t n = static_cast<std::size_t>(std::min<uint64_t>(pos - mPos, scratch.size()));
            const std::string problem = read(scratch.data(), n);
            if (!problem.empty()) return problem;
        }
        return "";
    }

    /// Reads exactly `n` bytes; "" or the problem in words (naming no file).
    std::string read(char* out, std::size_t n)
    {
        if (!mError.empty()) return mError;
        if (mGz) {
            const std::size_t got = mGz->read(out, n);
            mPos += got;
            if (got == n) return "";
            if (!mGz->error().empty()) {
                mError = mGz->error();
            } else {
                const uint64_t need = mLayout.offset + static_cast<uint64_t>(mLayout.size[0] * mLayout.size[1] *
                                                                             mLayout.size[2]) * mLayout.componentBytes;
                mError = "header/data size mismatch: the header needs " + std::to_string(need) +
                         " bytes, the decompressed file holds " + std::to_string(mPos) + " (truncated?)";
            }
            return mError;
        }
        std::size_t done = 0;
        while (done < n) {
            const ssize_t got = ::pread(mFd, out + done, n - done, static_cast<off_t>(mPos));
            if (got < 0 && errno == EINTR) continue;
            if (got <= 0) {
                mError = "cannot read the voxel data: " +
                         (got < 0 ? std::string(std::strerror(errno)) : std::string("the file ends early"));
                return mError;
            }
            done += static_cast<std::size_t>(got);
            mPos += static_cast<uint64_t>(got);
        }
        return "";
    }

    /// After the last voxel: the rest of the gzip data, so that the trailer of the last member
    /// (its CRC-32 and length) is checked as well. "" or the problem.
    std::string finish()
    {
        if (!mError.empty()) return mError;
        if (mGz && !mGz->readToEnd()) mError = mGz->error();
        return mError;
    }

private:
    const std::string& mName;
    const RawLayout& mLayout;
    std::unique_ptr<GzipStream> mGz;
    int mFd = -1;
    uint64_t mPos = 0;
    std::string mError;
};

} // namespace

RawVoxels::RawVoxels(std::string name, RawLayout layout) : mName(std::move(name)), mLayout(std::move(layout))
{
    if (mLayout.componentBytes == 0 || mLayout.size[0] < 1 || mLayout.size[1] < 1 || mLayout.size[2] < 1)
        throw std::logic_error("RawVoxels: empty layout");
    mSliceVoxels = static_cast<std::size_t>(mLayout.size[0] * mLayout.size[1]);
    mBlockSlices = std::max<int64_t>(1, static_cast<int64_t>(BLOCK_BYTES / (mSliceVoxels * sizeof(float))));
}

RawVoxels::~RawVoxels() { stop(); }

void RawVoxels::start(int64_t fromSlice)
{
    mStarted = fromSlice;
    mDone = false;
    mStop = false;
    mProducer = std::thread([this, fromSlice] { produce(fromSlice); });
}

void RawVoxels::stop()
{
    {
        std::lock_guard<std::mutex> lock(mMutex);
        mStop = true;
    }
    mChanged.notify_all();
    if (mProducer.joinable()) mProducer.join();
    std::lock_guard<std::mutex> lock(mMutex);
    mBlocks.clear();
    mFree.clear();
    mStop = false;
    mDone = false;
}

void RawVoxels::produce(int64_t fromSlice)
{
    auto push = [&](std::unique_ptr<Block> block) {
        std::lock_guard<std::mutex> lock(mMutex);
        mBlocks.push_back(std::move(block));
        mChanged.notify_all();
    };
    try {
        ByteReader reader(mName, mLayout);
        const std::size_t sliceBytes = mSliceVoxels * mLayout.componentBytes;
        std::string problem =
            reader.skipTo(mLayout.offset + static_cast<uint64_t>(fromSlice) * static_cast<uint64_t>(sliceBytes));
        std::vector<char> native;
        for (int64_t k0 = fromSlice; k0 < mLayout.size[2]; k0 += mBlockSlices) {
            std::unique_ptr<Block> block;
            {
                std::unique_lock<std::mutex> lock(mMutex);
                mChanged.wait(lock, [&] { return mStop || mBlocks.size() < BLOCKS_AHEAD; });
                if (mStop) return;
                if (!mFree.empty()) {  // reuse a passed block's memory (fresh pages cost page faults)
                    block = std::move(mFree.back());
                    mFree.pop_back();
                }
            }
            if (!block) block = std::make_unique<Block>();
            block->k0 = k0;
            block->count = 0;
            block->error.clear();
            const int64_t count = std::min(mBlockSlices, mLayout.size[2] - k0);
            const std::size_t n = mSliceVoxels * static_cast<std::size_t>(count);
            native.resize(n * mLayout.componentBytes);
            if (problem.empty()) problem = reader.read(native.data(), native.size());
            if (problem.empty() && k0 + count == mLayout.size[2]) problem = reader.finish();
            if (!problem.empty()) {
                block->error = mName + ": " + problem;
                push(std::move(block));
                break;
            }
            if (mLayout.swapped && mLayout.componentBytes > 1)
                for (std::size_t i = 0; i < n; ++i) {
                    char* v = native.data() + i * mLayout.componentBytes;
                    std::reverse(v, v + mLayout.componentBytes);
                }
            block->values.resize(n);
            float* out = block->values.data();
            try {
                const std::size_t bad = toFloat(native.data(), mLayout.type, n, out);
                if (bad < n) throwNonFinite(mName, mLayout.size, k0, bad, out[bad]);
                if (mLayout.scaled)
                    for (std::size_t i = 0; i < n; ++i) {
                        // As ITK's NiftiImageIO: the stored value as float, times the slope and
                        // plus the intercept in double, back to float.
                        out[i] = static_cast<float>(static_cast<double>(out[i]) * mLayout.slope + mLayout.inter);
                        if (!std::isfinite(out[i])) throwNonFinite(mName, mLayout.size, k0, i, out[i]);
                    }
            } catch (const InputError& e) {
                block->values.clear();
                block->error = e.what();
                push(std::move(block));
                break;
            }
            block->count = count;
            push(std::move(block));
        }
    } catch (const std::exception& e) {  // out of memory, thread trouble: reported to the consumer
        auto block = std::make_unique<Block>();
        block->k0 = fromSlice;
        block->error = mName + ": cannot read the voxel data: " + e.what();
        push(std::move(block));
    }
    std::lock_guard<std::mutex> lock(mMutex);
    mDone = true;
    mChanged.notify_all();
}

const RawVoxels::Block* RawVoxels::blockWith(int64_t k, std::unique_lock<std::mutex>& lock)
{
    for (;;) {
        bool popped = false;
        while (!mBlocks.empty() && mBlocks.front()->error.empty() && mBlocks.front()->k0 + mBlocks.front()->count <= k) {
            mFree.push_back(std::move(mBlocks.front()));
            mBlocks.pop_front();
            popped = true;
        }
        if (popped) mChanged.notify_all();
        if (!mBlocks.empty()) {
            const Block& front = *mBlocks.front();
            if (k < front.k0) return nullptr;  // already passed: start again
            if (!front.error.empty()) throw InputError(front.error);
            return &front;
        }
        if (mDone) return nullptr;
        mChanged.wait(lock);
    }
}

void RawVoxels::readSlices(int64_t k0, int64_t k1, float* out)
{
    if (!(0 <= k0 && k0 < k1 && k1 <= mLayout.size[2])) throw std::out_of_range("readSlices: slice range");
    if (!mProducer.joinable() || k0 < mStarted) {
        stop();
        start(k0);
    }
    for (int64_t k = k0; k < k1;) {
        const Block* block = nullptr;
        {
            std::unique_lock<std::mutex> lock(mMutex);
            block = blockWith(k, lock);
        }
        if (!block) {
            stop();
            start(k);
            continue;
        }
        // Only this thread removes blocks, so the block stays while it is copied.
        const int64_t end = std::min(k1, block->k0 + block->count);
        std::memcpy(out + mSliceVoxels * static_cast<std::size_t>(k - k0),
                    block->values.data() + mSliceVoxels * static_cast<std::size_t>(k - block->k0),
                    mSliceVoxels * static_cast<std::size_t>(end - k) * sizeof(float));
        k = end;
    }
}

} // namespace flyover::imageio
