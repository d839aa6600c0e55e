/// @file raw_voxels.h
/// @brief The voxels of a NIfTI file (k slowest, then j, then i), read by slices straight from
///        the file: by pread when it is uncompressed, inflated by ISA-L while read when it is
///        gzipped (gzip_stream.h; no temporary copy). A thread reads, byte-swaps, converts to
///        float and scales a few slices ahead of the consumer, so that inflating overlaps the
///        consumer's work. Internal to volume/.
///
/// gzip: truncated and corrupt streams are reported (ITK's readers zero-fill them); they are
/// reported when the consumer reaches the slices that are missing, in one line naming the
/// file. Reading backwards restarts the inflation from the start of the file.
#pragma once

#include "volume/io/pixel_convert.h"

#include <array>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace flyover::imageio {

/// How the voxels lie in the data file.
struct RawLayout {
    std::string dataPath;        ///< the file holding the voxels
    bool compressed = false;     ///< gzip (inflated by ISA-L, gzip_stream.h)
    uint64_t offset = 0;         ///< bytes before voxel (0,0,0) (of the decompressed stream)
    IOComponentEnum type = IOComponentEnum::UNKNOWNCOMPONENTTYPE;
    std::size_t componentBytes = 0;
    bool swapped = false;        ///< stored in the other byte order
    bool scaled = false;         ///< value = stored * slope + inter (as ITK and niftilib apply it)
    double slope = 1, inter = 0;
    std::array<int64_t, 3> size{0, 0, 0};
};

class RawVoxels {
public:
    /// `name` is the file named in messages.
    RawVoxels(std::string name, RawLayout layout);
    ~RawVoxels();
    RawVoxels(const RawVoxels&) = delete;
    RawVoxels& operator=(const RawVoxels&) = delete;

    /// Slices [k0, k1) as float, x fastest (ImageSource::readSlices).
    /// @throw InputError naming the file: truncated or corrupt data, NaN or Inf voxels.
    void readSlices(int64_t k0, int64_t k1, float* out);

private:
    /// Slices [k0, k0 + count) as float, or the error met instead of them.
    struct Block {
        int64_t k0 = 0, count = 0;
        std::vector<float> values;
        std::string error;
    };

    void start(int64_t fromSlice);
    void stop();
    void produce(int64_t fromSlice);
    /// The block holding slice k (waiting for it); null when the producer is past it.
    const Block* blockWith(int64_t k, std::unique_lock<std::mutex>& lock);

    std::string mName;
    RawLayout mLayout;
    std::size_t mSliceVoxels = 0;
    int64_t mBlockSlices = 1;

    std::mutex mMutex;
    std::condition_variable mChanged;
    std::deque<std::unique_ptr<Block>> mBlocks;  ///< produced, not yet passed by the consumer
    std::vector<std::unique_ptr<Block>> mFree;   ///< passed, their memory kept for reuse
    bool mStop = false;
    bool mDone = false;       ///< the producer delivered its last block
    int64_t mStarted = 0;     ///< the slice the producer started from
    std::thread mProducer;
};

} // namespace flyover::imageio
