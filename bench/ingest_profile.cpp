// Where ingest's time goes: the steps of `flyover run`'s ingest stage on one scan,
// one after the other in this process, each with its wall seconds and the process's CPU
// seconds (user + system, all threads: what a busy machine does not inflate).
//
//   ingest_profile FILE [REPEATS]
//
// Steps: the input digest (the cache key's input), openImage (header probe in a child, header
// checks, and before flyover read NIfTI voxels itself, the inflation of a .nii.gz), ingestImage
// split into reading slices (the source's readSlices: file IO, decompression and conversion to
// float unless a reading thread does them ahead) and the rest (resampling, outside-air
// marking, leaf building; with a reading thread, its CPU too), the .vdb write (writeGrids as
// the ingest stage calls it, with the deterministic UUID), and the digest of the written file
// (which the next stage's key needs).
// With REPEATS > 1 each figure is the median. Last, for comparison only, the same grid written
// with Blosc. Writes into a private temporary folder only.

#include "pipeline/artifact_io.h"
#include "pipeline/grid_write.h"
#include "pipeline/artifact_store.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <openvdb/openvdb.h>

#include <tbb/global_control.h>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

struct Sample {
    double wall = 0, cpu = 0;
};

double cpuSeconds()
{
    rusage u{};
    ::getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

class Timer {
public:
    Timer() : mWall(std::chrono::steady_clock::now()), mCpu(cpuSeconds()) {}
    Sample elapsed() const
    {
        return {std::chrono::duration<double>(std::chrono::steady_clock::now() - mWall).count(), cpuSeconds() - mCpu};
    }

private:
    std::chrono::steady_clock::time_point mWall;
    double mCpu;
};

/// Forwards to a source and adds up the time spent in its readSlices.
class TimedSource final : public ImageSource {
public:
    explicit TimedSource(ImageSource& inner) : mInner(inner)
    {
        mName = inner.name();
        mGeometry = inner.geometry();
        mRegular = inner.isRegular();
        mSliceOriginsMm = inner.sliceOriginsMm();
        mWarnings = inner.warnings();
        mDescription = inner.description();
        mHeldBytes = inner.heldBytes();
    }
    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const Timer t;
        mInner.readSlices(k0, k1, out);
        const Sample s = t.elapsed();
        read.wall += s.wall;
        read.cpu += s.cpu;
    }
    Sample read;

private:
    ImageSource& mInner;
};

double median(std::vector<double> v)
{
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

} // namespace

int main(int argc, char** argv)
{
    if (argc < 2) {
        std::cerr << "usage: ingest_profile FILE [REPEATS]\n";
        return 2;
    }
    const std::string path = argv[1];
    const int repeats = argc >= 3 ? std::max(1, std::atoi(argv[2])) : 1;
    openvdb::initialize();
    const fs::path dir = fs::temp_directory_path() / ("flyover-ingest-profile-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const std::vector<std::string> order{"input digest", "openImage", "  read slices", "  build grid",
                                         "ingestImage", ".vdb write", ".vdb digest", "total", "(with Blosc)",
                                         "(read alone)", "(grid, 1 thread)", "(grid, 2 threads)"};
    std::map<std::string, std::vector<double>> wall, cpu;
    std::string reader;
    uintmax_t bloscBytes = 0;
    try {
        for (int r = 0; r < repeats; ++r) {
            std::map<std::string, Sample> s;
            const Timer total;
            Timer t;
            const std::string inputDigest = artifactDigest(path);
            s["input digest"] = t.elapsed();
            t = Timer();
            auto source = openImage(path);
            s["openImage"] = t.elapsed();
            reader = source->description();
            TimedSource timed(*source);
            t = Timer();
            auto grid = ingestImage(timed, IngestParams{});
            s["ingestImage"] = t.elapsed();
            s["  read slices"] = timed.read;
            s["  build grid"] = {s["ingestImage"].wall - timed.read.wall, s["ingestImage"].cpu - timed.read.cpu};
            source.reset();
            const std::string vdb = (dir / "ct.vdb").string();
            t = Timer();
            writeGrids(vdb, {grid}, VdbValues::Raw);  // as the ingest stage writes ct.vdb
            s[".vdb write"] = t.elapsed();
            t = Timer();
            const std::string digest = artifactDigest(vdb);
            s[".vdb digest"] = t.elapsed();
            s["total"] = total.elapsed();  // up to here: the steps of the ingest stage
            {  // for comparison: the same grid with Blosc (as ct.vdb was written before)
                t = Timer();
                writeGrids((dir / "blosc.vdb").string(), {grid}, VdbValues::Blosc);
                s["(with Blosc)"] = t.elapsed();
                bloscBytes = fs::file_size(dir / "blosc.vdb");
            }
            {  // for comparison: the two halves of ingestImage apart. The source read alone (by
               // slabs of 8, as ingest reads it: the inflation and conversion), then the grid
               // built from those voxels in memory, on one thread and on two.
                auto again = openImage(path);
                Image3<float> image;
                image.geometry = again->geometry();
                image.voxels.resize(static_cast<std::size_t>(image.geometry.voxelCount()));
                const int64_t nk = image.geometry.size[2];
                const std::size_t perSlice = static_cast<std::size_t>(image.geometry.size[0] * image.geometry.size[1]);
                t = Timer();
                for (int64_t k = 0; k < nk; k += 8)
                    again->readSlices(k, std::min(nk, k + 8), image.voxels.data() + perSlice * static_cast<std::size_t>(k));
                s["(read alone)"] = t.elapsed();
                again.reset();
                for (int threads : {1, 2}) {
                    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
                    t = Timer();
                    auto copy = ingestImage(image, IngestParams{});
                    s[threads == 1 ? "(grid, 1 thread)" : "(grid, 2 threads)"] = t.elapsed();
                }
            }
            for (const auto& [k, v] : s) {
                wall[k].push_back(v.wall);
                cpu[k].push_back(v.cpu);
            }
            if (r == 0) std::cout << "ct.vdb digest " << digest << ", " << fs::file_size(vdb) << " bytes, "
                                  << grid->activeVoxelCount() << " active voxels\n";
        }
    } catch (const std::exception& e) {
        std::cerr << "ingest_profile: " << e.what() << "\n";
        fs::remove_all(dir);
        return 1;
    }
    fs::remove_all(dir);
    std::cout << path << "\nreader: " << reader << "\n";
    std::printf("%-16s %10s %10s   (median of %d)\n", "step", "wall s", "cpu s", repeats);
    for (const auto& k : order) std::printf("%-16s %10.3f %10.3f\n", k.c_str(), median(wall[k]), median(cpu[k]));
    std::printf("(with Blosc): the .vdb written with Blosc, for comparison: %ju bytes\n", bloscBytes);
    std::printf("(read alone): a fresh source's readSlices by 8 slices into memory; (grid, N threads):\n"
                "ingestImage of those voxels from memory with N threads (the two halves of ingestImage apart)\n");
    return 0;
}
