// surface_bench: the mesh stage's work (surface/lumen_surface.h: volumeToMesh extraction with
// its orientation check, Taubin smoothing with its orientation guard, and the final checks)
// on a phantom's lumen level set.
//
//   surface_bench [--size full|medium|small] [--runs N] [--decimate-fraction F] [--stage mesh|centerline]
//
// --stage centerline times the centerline stage instead (colon/centerline.h: the distance
// field is the lumen level set itself; medial minimal path, centring on sections, smoothing,
// bridging, resampling) on the same level set, against its target of under 3 s on 2 cores.
//
// The phantom is generated, ingested and segmented once; the lumen level set is saved as a
// temporary .vdb. Each measured run is a fresh child process (this program with --grid FILE)
// that loads only the level set, so its peak resident memory is that of one mesh stage plus
// the grid, not of the phantom generator. Prints the median and range of N runs: wall time
// (and its parts), triangle count, resident memory after loading the grid and at its peak.
#include "bench/process_memory.h"
#include "colon/phantom.h"
#include "surface/lumen_surface.h"
#include "colon/centerline.h"
#include "volume/ingest.h"
#include "colon/segment.h"

#include <openvdb/openvdb.h>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

using bench::currentRssMb;
using bench::peakRssMb;

/// One run's figures, as the child prints them on one line.
struct Run {
    double seconds = 0, extract = 0, smooth = 0, decimate = 0, check = 0;
    double faces = 0, loadedMb = 0, peakMb = 0, inward = 0, volumeChange = 0;
    double points = 0, lengthMm = 0;  ///< --stage centerline
};

int child(const std::string& gridPath, double decimateFraction, const std::string& stage)
{
    openvdb::initialize();
    openvdb::io::File file(gridPath);
    file.open();
    const auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("lumen_sdf"));
    file.close();
    const double loadedMb = currentRssMb();
    if (stage == "centerline") {
        const auto t0 = std::chrono::steady_clock::now();
        const Centerline cl = extractCenterline(*sdf, CenterlineParams{});
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::printf("%.4f 0 0 0 0 0 %.1f %.1f 0 0 %zu %.3f\n", seconds, loadedMb, peakRssMb(), cl.points.size(),
                    cl.lengthMm());
        return 0;
    }
    MeshParams params;
    params.decimateFraction = decimateFraction;
    LumenSurfaceReport rep;
    const auto t0 = std::chrono::steady_clock::now();
    const TriMesh mesh = makeLumenSurface(*sdf, params, &rep);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%.4f %.4f %.4f %.4f %.4f %zu %.1f %.1f %.9f %.6f 0 0\n", seconds, rep.extractSeconds, rep.smoothSeconds,
                rep.decimateSeconds, rep.checkSeconds, mesh.n_faces(), loadedMb, peakRssMb(),
                rep.orientation.inwardFraction(), rep.smoothingVolumeChange);
    return 0;
}

Run runChild(const std::string& self, const std::string& grid, double decimateFraction, const std::string& stage)
{
    const std::string cmd = "'" + self + "' --grid '" + grid + "' --decimate-fraction " +
                            std::to_string(decimateFraction) + " --stage " + stage;
    FILE* pipe = ::popen(cmd.c_str(), "r");
    if (!pipe) throw std::runtime_error("cannot run " + cmd);
    char buffer[1024];
    std::string out;
    while (std::fgets(buffer, sizeof buffer, pipe)) out += buffer;
    if (::pclose(pipe) != 0) throw std::runtime_error(cmd + " failed:\n" + out);
    std::istringstream in(out);
    Run r;
    if (!(in >> r.seconds >> r.extract >> r.smooth >> r.decimate >> r.check >> r.faces >> r.loadedMb >> r.peakMb >>
          r.inward >> r.volumeChange >> r.points >> r.lengthMm))
        throw std::runtime_error(cmd + ": unexpected output:\n" + out);
    return r;
}

/// Median, min and max of one figure over the runs.
std::string spread(std::vector<Run> runs, double Run::*field, const char* format)
{
    std::sort(runs.begin(), runs.end(), [&](const Run& a, const Run& b) { return a.*field < b.*field; });
    char text[128];
    std::snprintf(text, sizeof text, format, runs[runs.size() / 2].*field, runs.front().*field, runs.back().*field);
    return text;
}

} // namespace

int main(int argc, char** argv)
{
    std::string size = "full", grid, stage = "mesh";
    int runs = 5;
    double decimateFraction = 1.0;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--size" && i + 1 < argc) size = argv[++i];
        else if (a == "--runs" && i + 1 < argc) runs = std::max(1, std::atoi(argv[++i]));
        else if (a == "--grid" && i + 1 < argc) grid = argv[++i];
        else if (a == "--decimate-fraction" && i + 1 < argc) decimateFraction = std::atof(argv[++i]);
        else if (a == "--stage" && i + 1 < argc && (std::string(argv[i + 1]) == "mesh" || std::string(argv[i + 1]) == "centerline"))
            stage = argv[++i];
        else {
            std::cerr << "usage: surface_bench [--size full|medium|small] [--runs N] [--decimate-fraction F] "
                         "[--stage mesh|centerline]\n";
            return 2;
        }
    }
    try {
        if (!grid.empty()) return child(grid, decimateFraction, stage);

        openvdb::initialize();
        PhantomParams pp;
        pp.size = parsePhantomSize(size);
        const auto t0 = std::chrono::steady_clock::now();
        const fs::path tmp = fs::temp_directory_path() / ("surface_bench_" + std::to_string(::getpid()) + ".vdb");
        {
            Phantom ph = makePhantom(pp);
            const double truthMl = ph.truth.lumenVolumeMl;
            Image3<float> ct;
            ct.geometry = ph.ct.geometry;
            ct.voxels.assign(ph.ct.voxels.begin(), ph.ct.voxels.end());
            ph = Phantom{};
            const openvdb::FloatGrid::Ptr hu = ingestImage(ct, IngestParams{});
            ct = Image3<float>{};
            const LumenSegmentation seg = segmentLumen(*hu, SegmentParams{});
            openvdb::io::File file(tmp.string());
            file.write({seg.sdf});
            std::printf("phantom %s (seed %llu): lumen level set of %.4g mm voxels, %lld active voxels; lumen "
                        "%.1f mL (truth %.1f mL); built in %.1f s\n",
                        size.c_str(), (unsigned long long)pp.seed, seg.sdf->voxelSize()[0],
                        (long long)seg.sdf->activeVoxelCount(), seg.lumenVolumeMl, truthMl,
                        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        }
        const std::string self = fs::read_symlink("/proc/self/exe").string();
        std::vector<Run> results;
        for (int r = 0; r < runs; ++r) results.push_back(runChild(self, tmp.string(), decimateFraction, stage));
        fs::remove(tmp);
        if (stage == "centerline") {
            std::printf("extractCenterline (default parameters), %d runs, median (min..max):\n", runs);
            std::printf("  total          %s\n", spread(results, &Run::seconds, "%.3f s (%.3f..%.3f)").c_str());
            std::printf("  points         %.0f, length %.1f mm\n", results.front().points, results.front().lengthMm);
            std::printf("  resident       %s after loading the level set, peak %s\n",
                        spread(results, &Run::loadedMb, "%.0f MB").c_str(),
                        spread(results, &Run::peakMb, "%.0f MB (%.0f..%.0f)").c_str());
            return 0;
        }

        std::printf("makeLumenSurface (default parameters%s), %d runs, median (min..max):\n",
                    decimateFraction < 1.0 ? (", decimate_fraction " + std::to_string(decimateFraction)).c_str() : "",
                    runs);
        std::printf("  total          %s\n", spread(results, &Run::seconds, "%.3f s (%.3f..%.3f)").c_str());
        std::printf("    extraction   %s  volumeToMesh, quads split, orientation, OpenMesh\n",
                    spread(results, &Run::extract, "%.3f s (%.3f..%.3f)").c_str());
        std::printf("    smoothing    %s  Taubin and its orientation guard\n",
                    spread(results, &Run::smooth, "%.3f s (%.3f..%.3f)").c_str());
        if (decimateFraction < 1.0)
            std::printf("    decimation   %s\n", spread(results, &Run::decimate, "%.3f s (%.3f..%.3f)").c_str());
        std::printf("    checks       %s  topology, volumes, per-face orientation%s\n",
                    spread(results, &Run::check, "%.3f s (%.3f..%.3f)").c_str(),
                    decimateFraction < 1.0 ? ", Hausdorff" : "");
        std::printf("  triangles      %.0f\n", results.front().faces);
        std::printf("  inward faces   %.6f%%, smoothing volume change %+.4f%%\n", 100 * results.front().inward,
                    100 * results.front().volumeChange);
        std::printf("  resident       %s after loading the level set, peak %s\n",
                    spread(results, &Run::loadedMb, "%.0f MB").c_str(),
                    spread(results, &Run::peakMb, "%.0f MB (%.0f..%.0f)").c_str());
    } catch (const std::exception& e) {
        std::cerr << "surface_bench: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
