// Ingest benchmark: time and peak memory of reading a scan into the sparse HU grid, against
// a plain read of the same file by ITK alone. A small program printing figures (not Google
// Benchmark): each measurement runs in a child process, and its peak RSS is taken from
// wait4()'s rusage, the number /usr/bin/time -v prints as "Maximum resident set size".
//
//   ingest_bench full-phantom DIR          DIR/full.nii.gz and DIR/full.nii: the 512x512x450
//                                          phantom of `flyover phantom --size full`
//   ingest_bench generate OUT.mha N        an N^3 int16 phantom-kind volume, streamed to disk
//                                          slab by slab by ITK's MetaImageIO (N=1024: 2 GiB)
//   ingest_bench compare FILE [REPEATS]    medians of REPEATS (default 3) plain ITK reads and
//                                          ingests (+ compressed .vdb write) of FILE, their
//                                          ratio, and the peak-memory bound check
//   ingest_bench itk-read FILE             one plain ITK read (child of compare)
//   ingest_bench ingest FILE [OUT.vdb]     one ingest (child of compare); prints a JSON line
//   ingest_bench baseline                  loads the libraries and exits (RSS floor)

#include "volume/seconds_since.h"
#include "colon/phantom.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkMetaImageIO.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <openvdb/openvdb.h>
#include <tbb/parallel_for.h>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

using Clock = std::chrono::steady_clock;


// ------------------------------------------------------------------ phantom-kind generator

uint64_t mix(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

/// The anatomy of data/phantom in broad strokes (body with a fat layer, spine, lungs, an
/// air-filled colon loop, small-bowel gas, 15 HU noise) in a 400 mm field of view, cheap
/// enough to voxelise 10^9 voxels in seconds: what matters here is the sparsity.
struct BenchPhantom {
    struct Segment { Vec3d a, b; };
    std::vector<Segment> colon;
    std::vector<Vec3d> gas;
    static constexpr double COLON_RADIUS_MM = 22.0;

    BenchPhantom()
    {
        const std::vector<Vec3d> path{{0, 40, -170},  {0, 30, -130},  {40, 0, -110},   {95, -10, -100}, {95, -10, 50},
                                      {80, -30, 80},  {0, -70, 60},   {-80, -30, 80},  {-95, -10, 50},  {-95, -10, -90}};
        for (std::size_t i = 0; i + 1 < path.size(); ++i) colon.push_back({path[i], path[i + 1]});
        gas = {{-30, -20, -40}, {20, -40, -20}, {-40, 10, 0}, {35, 15, -60}, {-10, -50, 10}, {10, 20, -90}};
    }

    static double segmentDistance(const Vec3d& p, const Segment& s)
    {
        const Vec3d d = s.b - s.a;
        const double t = std::clamp(dot(p - s.a, d) / dot(d, d), 0.0, 1.0);
        return distance(p, s.a + t * d);
    }

    /// Fills one axial slice (z in mm) of n x n voxels of `voxelMm`.
    void slice(int64_t n, double voxelMm, int64_t k, int16_t* out) const
    {
        const double z = -200.0 + (double(k) + 0.5) * voxelMm;
        std::vector<const Segment*> near;
        for (const auto& s : colon)
            if (z >= std::min(s.a.z, s.b.z) - COLON_RADIUS_MM - 3 && z <= std::max(s.a.z, s.b.z) + COLON_RADIUS_MM + 3)
                near.push_back(&s);
        for (int64_t j = 0; j < n; ++j) {
            const double y = -200.0 + (double(j) + 0.5) * voxelMm;
            for (int64_t i = 0; i < n; ++i) {
                const double x = -200.0 + (double(i) + 0.5) * voxelMm;
                const uint64_t h = mix(static_cast<uint64_t>((k * n + j) * n + i));
                // Sum of four uniforms: close enough to Gaussian noise of 15 HU.
                const double noise = (double((h & 0xFFFF) + ((h >> 16) & 0xFFFF) + ((h >> 32) & 0xFFFF) + (h >> 48)) /
                                          65535.0 - 2.0) * 15.0 * std::sqrt(3.0);
                const double ry = y < 0 ? 130.0 : 120.0;
                double hu;
                if ((x / 170) * (x / 170) + (y / ry) * (y / ry) > 1.0) {
                    hu = -1000.0;
                } else {
                    const double fy = y < 0 ? 113.0 : 103.0;
                    hu = (x / 153) * (x / 153) + (y / fy) * (y / fy) > 1.0 ? -100.0 : 40.0;
                    const double spine = std::hypot(x, y - 65.0);
                    if (spine < 20.0) hu = spine > 17.5 ? 1200.0 : 700.0;
                    for (double side : {-85.0, 85.0}) {
                        const double ex = (x - side) / 65, ey = (y - 10) / 75, ez = (z - 170) / 110;
                        if (ex * ex + ey * ey + ez * ez < 1.0) hu = -850.0;
                    }
                    const Vec3d p{x, y, z};
                    for (const Segment* s : near)
                        if (segmentDistance(p, *s) < COLON_RADIUS_MM) { hu = -1000.0; break; }
                    for (const Vec3d& g : gas)
                        if (distance(p, g) < 8.0) hu = -1000.0;
                }
                out[j * n + i] = static_cast<int16_t>(std::clamp(std::lround(hu + noise), -1024L, 3071L));
            }
        }
    }
};

int generate(const std::string& path, int64_t n)
{
    itk::MetaImageIOFactory::RegisterOneFactory();
    const double voxelMm = 400.0 / double(n);
    auto io = itk::MetaImageIO::New();
    io->SetNumberOfDimensions(3);
    for (unsigned d = 0; d < 3; ++d) {
        io->SetDimensions(d, static_cast<unsigned>(n));
        io->SetSpacing(d, voxelMm);
        io->SetOrigin(d, -200.0 + 0.5 * voxelMm);
        std::vector<double> dir(3, 0.0);
        dir[d] = 1.0;
        io->SetDirection(d, dir);
    }
    io->SetComponentType(itk::IOComponentEnum::SHORT);
    io->SetPixelType(itk::IOPixelEnum::SCALAR);
    io->SetNumberOfComponents(1);
    io->SetUseCompression(false);
    io->SetFileName(path);
    fs::remove(path);
    const BenchPhantom phantom;
    const int64_t slab = 16;
    std::vector<int16_t> buf(static_cast<std::size_t>(n * n * slab));
    const auto t0 = Clock::now();
    for (int64_t k0 = 0; k0 < n; k0 += slab) {
        const int64_t k1 = std::min(n, k0 + slab);
        tbb::parallel_for(k0, k1, [&](int64_t k) { phantom.slice(n, voxelMm, k, buf.data() + (k - k0) * n * n); });
        itk::ImageIORegion region(3);
        for (unsigned d = 0; d < 3; ++d) {
            region.SetIndex(d, 0);
            region.SetSize(d, static_cast<itk::SizeValueType>(n));
        }
        region.SetIndex(2, k0);
        region.SetSize(2, static_cast<itk::SizeValueType>(k1 - k0));
        io->SetIORegion(region);
        io->Write(buf.data());
    }
    std::cout << "generated " << path << ": " << n << "^3 int16, " << voxelMm << " mm, "
              << double(fs::file_size(path)) / (1 << 30) << " GiB in " << secondsSince(t0) << " s\n";
    return 0;
}

int fullPhantom(const std::string& dir)
{
    fs::create_directories(dir);
    PhantomParams pp;
    pp.size = PhantomSize::Full;
    pp.seed = 1;
    const Phantom ph = makePhantom(pp);
    writeImage(ph.ct, (fs::path(dir) / "full.nii.gz").string());
    writeImage(ph.ct, (fs::path(dir) / "full.nii").string());
    std::cout << "wrote " << dir << "/full.nii.gz and full.nii (" << ph.ct.geometry.size[0] << "x"
              << ph.ct.geometry.size[1] << "x" << ph.ct.geometry.size[2] << ")\n";
    return 0;
}

// -------------------------------------------------------------------- one measurement each

int itkRead(const std::string& path)
{
    itk::NiftiImageIOFactory::RegisterOneFactory();
    itk::NrrdImageIOFactory::RegisterOneFactory();
    itk::MetaImageIOFactory::RegisterOneFactory();
    const auto t0 = Clock::now();
    auto reader = itk::ImageFileReader<itk::Image<int16_t, 3>>::New();
    reader->SetFileName(path);
    reader->Update();
    const double seconds = secondsSince(t0);
    const auto size = reader->GetOutput()->GetLargestPossibleRegion().GetSize();
    // A checksum, so that the read is known to have produced the voxels.
    const int16_t* v = reader->GetOutput()->GetBufferPointer();
    const std::size_t n = size[0] * size[1] * size[2];
    int64_t sum = 0;
    for (std::size_t i = 0; i < n; ++i) sum += v[i];
    std::cout << "{\"seconds\": " << seconds << ", \"voxels\": " << n << ", \"mean\": " << double(sum) / double(n)
              << "}\n";
    return 0;
}

int ingest(const std::string& path, const std::string& vdbPath)
{
    openvdb::initialize();
    const auto t0 = Clock::now();
    auto source = openImage(path);
    IngestReport rep;
    auto grid = ingestImage(*source, IngestParams{}, &rep);
    const double ingestSeconds = secondsSince(t0);
    source.reset();
    double writeSeconds = 0;
    uint64_t fileBytes = 0;
    if (!vdbPath.empty()) {
        const auto t1 = Clock::now();
        openvdb::io::File file(vdbPath);  // as pipeline/vdb_io.cpp writes ct.vdb
        file.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK | (openvdb::io::Archive::hasBloscCompression()
                                                                     ? openvdb::io::COMPRESS_BLOSC
                                                                     : openvdb::io::COMPRESS_ZIP));
        file.write({grid});
        file.close();
        writeSeconds = secondsSince(t1);
        fileBytes = fs::file_size(vdbPath);
    }
    rusage self{};
    ::getrusage(RUSAGE_SELF, &self);
    std::cout << "{\"seconds\": " << ingestSeconds << ", \"write_seconds\": " << writeSeconds
              << ", \"active_voxels\": " << rep.activeVoxels << ", \"grid_bytes\": " << rep.memoryBytes
              << ", \"held_bytes\": " << rep.sourceHeldBytes << ", \"working_bytes\": " << rep.workingBytes
              << ", \"file_bytes\": " << fileBytes << ", \"peak_rss_bytes\": " << self.ru_maxrss * 1024
              << ", \"reader\": \"" << rep.source << "\"}\n";
    return 0;
}

int baseline()
{
    openvdb::initialize();
    itk::NiftiImageIOFactory::RegisterOneFactory();
    std::cout << "{}\n";
    return 0;
}

// ------------------------------------------------------------------------------ compare

struct Run {
    double wallSeconds = 0;
    double peakRssBytes = 0;
    std::string output;
};

/// Runs this program with `args` in a child; wall time, peak RSS (wait4) and its stdout.
Run child(const std::vector<std::string>& args)
{
    int pipeFd[2];
    if (::pipe(pipeFd) != 0) throw std::runtime_error("pipe failed");
    const auto t0 = Clock::now();
    const pid_t pid = ::fork();
    if (pid == 0) {
        ::dup2(pipeFd[1], STDOUT_FILENO);
        ::close(pipeFd[0]);
        ::close(pipeFd[1]);
        std::vector<char*> argv;
        std::string self = fs::read_symlink("/proc/self/exe").string();
        argv.push_back(self.data());
        std::vector<std::string> copy = args;
        for (auto& a : copy) argv.push_back(a.data());
        argv.push_back(nullptr);
        ::execv(self.c_str(), argv.data());
        std::_Exit(127);
    }
    ::close(pipeFd[1]);
    Run r;
    char buf[4096];
    ssize_t n;
    while ((n = ::read(pipeFd[0], buf, sizeof buf)) > 0) r.output.append(buf, static_cast<std::size_t>(n));
    ::close(pipeFd[0]);
    int status = 0;
    rusage usage{};
    ::wait4(pid, &status, 0, &usage);
    r.wallSeconds = secondsSince(t0);
    r.peakRssBytes = double(usage.ru_maxrss) * 1024.0;
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
        throw std::runtime_error("child failed: " + args.front() + "\n" + r.output);
    return r;
}

double median(std::vector<double> v)
{
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

double jsonNumber(const std::string& json, const std::string& key)
{
    const auto p = json.find("\"" + key + "\": ");
    return p == std::string::npos ? 0.0 : std::atof(json.c_str() + p + key.size() + 4);
}

int compare(const std::string& path, int repeats)
{
    const double mib = 1024.0 * 1024.0;
    const Run floor = child({"baseline"});
    std::vector<double> readT, readRss, ingT, ingRss, writeT;
    std::string last;
    const std::string vdb = path + ".bench.vdb";
    for (int r = 0; r < repeats; ++r) {
        const Run a = child({"itk-read", path});
        readT.push_back(jsonNumber(a.output, "seconds"));
        readRss.push_back(a.peakRssBytes);
        const Run b = child({"ingest", path, vdb});
        ingT.push_back(jsonNumber(b.output, "seconds"));
        writeT.push_back(jsonNumber(b.output, "write_seconds"));
        ingRss.push_back(b.peakRssBytes);
        last = b.output;
        std::cerr << "  run " << r + 1 << ": ITK read " << readT.back() << " s, " << readRss.back() / mib
                  << " MiB; ingest " << ingT.back() << " s (+ write " << writeT.back() << " s), " << ingRss.back() / mib
                  << " MiB\n";
    }
    fs::remove(vdb);
    const double grid = jsonNumber(last, "grid_bytes"), held = jsonNumber(last, "held_bytes"),
                 working = jsonNumber(last, "working_bytes");
    const double bound = 1.5 * grid + working + held;
    std::cout.precision(4);
    std::cout << "file: " << path << " (" << double(fs::file_size(path)) / mib << " MiB)\n"
              << "reader: " << last.substr(last.find("\"reader\": ") + 11, last.rfind('"') - last.find("\"reader\": ") - 11) << "\n"
              << "medians of " << repeats << ":\n"
              << "  plain ITK read (int16):   " << median(readT) << " s, peak RSS " << median(readRss) / mib << " MiB\n"
              << "  ingest to sparse grid:    " << median(ingT) << " s, peak RSS " << median(ingRss) / mib << " MiB\n"
              << "  + compressed .vdb write:  " << median(writeT) << " s, file " << jsonNumber(last, "file_bytes") / mib << " MiB\n"
              << "  ratio ingest / ITK read:  " << median(ingT) / median(readT) << "\n"
              << "grid: " << jsonNumber(last, "active_voxels") << " active voxels, memUsage " << grid / mib << " MiB\n"
              << "bound 1.5 x grid + working slab " << working / mib << " MiB + reader-held " << held / mib
              << " MiB = " << bound / mib << " MiB; process floor (libraries) " << floor.peakRssBytes / mib << " MiB\n"
              << "peak RSS " << (median(ingRss) <= bound ? "within" : "OVER") << " the bound ("
              << median(ingRss) / bound * 100 << "%)\n";
    return 0;
}

} // namespace

int main(int argc, char** argv)
{
    try {
        const std::vector<std::string> a(argv + 1, argv + argc);
        if (a.size() >= 2 && a[0] == "full-phantom") return fullPhantom(a[1]);
        if (a.size() >= 3 && a[0] == "generate") return generate(a[1], std::stoll(a[2]));
        if (a.size() >= 2 && a[0] == "compare") return compare(a[1], a.size() >= 3 ? std::stoi(a[2]) : 3);
        if (a.size() >= 2 && a[0] == "itk-read") return itkRead(a[1]);
        if (a.size() >= 2 && a[0] == "ingest") return ingest(a[1], a.size() >= 3 ? a[2] : "");
        if (a.size() >= 1 && a[0] == "baseline") return baseline();
        std::cerr << "usage: ingest_bench full-phantom DIR | generate OUT.mha N | compare FILE [REPEATS] | "
                     "itk-read FILE | ingest FILE [OUT.vdb] | baseline\n";
        return 2;
    } catch (const std::exception& e) {  // itk::ExceptionObject included
        std::cerr << "ingest_bench: " << e.what() << "\n";
        return 1;
    }
}
