// Industrial part at scale: the part phantom written slab by slab, and the void
// analysis of a scan read slab by slab into a sparse grid. Prints wall and CPU time, peak RSS
// and the grids' own memory. Not a CTest test.
//
//   part_bench phantom N OUT.nii [TRUTH.json]   write an N^3 part phantom (streaming)
//   part_bench analyse CT [TRUTH.json]           read CT into a FloatGrid (every voxel active,
//                                                as an ingest that keeps every voxel), analysePart
#include "bench/process_memory.h"
#include "inspect/part_phantom.h"
#include "pipeline/artifact_io.h"
#include "inspect/part_phantom_io.h"
#include "volume/image_io.h"
#include "inspect/voids.h"

#include <openvdb/openvdb.h>
#include <tbb/parallel_for.h>
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>

using namespace flyover;

namespace {

double cpuSeconds()
{
    rusage u{};
    ::getrusage(RUSAGE_SELF, &u);
    return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

struct Timer {
    std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
    double cpu0 = cpuSeconds();
    double wall() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); }
    double cpu() const { return cpuSeconds() - cpu0; }
};

double mb(double bytes) { return bytes / (1024.0 * 1024.0); }

int phantom(int n, const std::string& out, const std::string& truthPath)
{
    PartPhantomParams p;
    p.size = n;
    Timer t;
    const PartTruth truth = writePartPhantom(p, out, truthPath);
    std::printf("phantom %d^3 -> %s: %.1f s wall, %.1f s CPU, peak RSS %.0f MB, file %.0f MB, %zu voids, porosity %.4f%%\n",
                n, out.c_str(), t.wall(), t.cpu(), bench::peakRssMb(), mb(double(std::filesystem::file_size(out))),
                truth.voids.size(), truth.porosityPercent);
    std::printf("  (the volume as uint16 would be %.0f MB; one slice %.1f MB)\n", mb(2.0 * n * n * double(n)), mb(2.0 * n * n));
    return 0;
}

openvdb::FloatGrid::Ptr readGrid(const std::string& path, double& slabMb)
{
    auto src = openImage(path);
    const ImageGeometry g = src->geometry();
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto xf = openvdb::math::Transform::createLinearTransform(g.spacingMm.x);
    xf->postTranslate(openvdb::Vec3d(g.originMm.x, g.originMm.y, g.originMm.z));
    grid->setTransform(xf);
    const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
    const int64_t slab = 8;  // one leaf deep
    std::vector<float> buf(static_cast<std::size_t>(nx * ny * slab));
    slabMb = mb(double(buf.size() * sizeof(float)));
    using Leaf = openvdb::FloatTree::LeafNodeType;
    for (int64_t k0 = 0; k0 < nz; k0 += slab) {
        const int64_t k1 = std::min(nz, k0 + slab);
        src->readSlices(k0, k1, buf.data());
        const int64_t bx = (nx + 7) / 8, by = (ny + 7) / 8;
        std::vector<Leaf*> leaves(static_cast<std::size_t>(bx * by), nullptr);
        tbb::parallel_for(int64_t(0), bx * by, [&](int64_t b) {
            const int64_t x0 = (b % bx) * 8, y0 = (b / bx) * 8;
            auto* leaf = new Leaf(openvdb::Coord(int(x0), int(y0), int(k0)), 0.0f, false);
            for (int64_t z = k0; z < k1; ++z)
                for (int64_t y = y0; y < std::min(ny, y0 + 8); ++y)
                    for (int64_t x = x0; x < std::min(nx, x0 + 8); ++x)
                        leaf->setValueOn(openvdb::Coord(int(x), int(y), int(z)),
                                         buf[static_cast<std::size_t>(((z - k0) * ny + y) * nx + x)]);
            leaves[static_cast<std::size_t>(b)] = leaf;
        });
        for (Leaf* leaf : leaves) grid->tree().addLeaf(leaf);
    }
    return grid;
}

int analyse(const std::string& path, const std::string& truthPath)
{
    Timer tl;
    double slabMb = 0;
    const auto ct = readGrid(path, slabMb);
    const double ctMb = mb(double(ct->memUsage()));
    std::printf("read %s into a FloatGrid: %.1f s wall, %.1f s CPU; grid %.0f MB (%llu active voxels), slab %.0f MB, "
                "peak RSS so far %.0f MB\n",
                path.c_str(), tl.wall(), tl.cpu(), ctMb, static_cast<unsigned long long>(ct->activeVoxelCount()), slabMb,
                bench::peakRssMb());
    const double rssBefore = bench::currentRssMb();
    Timer ta;
    // the time of each step, as analysePart reports them
    struct StepClock : Progress {
        Timer t;
        std::string last = "start";
        double lastWall = 0, lastCpu = 0;
        void update(double, const std::string& what) override
        {
            if (what == last) return;
            std::printf("    %-18s %6.1f s wall %6.1f s CPU\n", last.c_str(), t.wall() - lastWall, t.cpu() - lastCpu);
            last = what;
            lastWall = t.wall();
            lastCpu = t.cpu();
        }
    } clock;
    const PartAnalysis a = analysePart(*ct, VoidParams{}, path, &clock);
    const double gridsMb = mb(double(a.material->memUsage() + a.outsideAir->memUsage() + a.voidLabels->memUsage()));
    std::printf("analysePart: %.1f s wall, %.1f s CPU; threshold %.1f (%s); %zu voids listed, %lld small; porosity %.5f%%\n",
                ta.wall(), ta.cpu(), a.threshold, a.thresholdSource.c_str(), a.voids.size(),
                static_cast<long long>(a.smallVoidCount), a.porosityPercent);
    std::printf("  RSS before %.0f MB, peak RSS %.0f MB; result grids (material, outside air, labels) %.0f MB; "
                "peak / (CT grid + result grids + slab) = %.2f\n",
                rssBefore, bench::peakRssMb(), gridsMb, bench::peakRssMb() / (ctMb + gridsMb + slabMb));
    if (!truthPath.empty()) {
        const nlohmann::json t = readJson(truthPath);
        const double vox = t.at("voxel_mm").get<double>();
        int internal = 0, found = 0, kindsRight = 0;
        double worstVolume = 0;
        for (const auto& v : t.at("voids")) {
            if (!v.at("internal").get<bool>()) continue;
            ++internal;
            const Vec3d c{v.at("centroid_lps_mm")[0].get<double>(), v.at("centroid_lps_mm")[1].get<double>(),
                          v.at("centroid_lps_mm")[2].get<double>()};
            for (const VoidInfo& f : a.voids)
                if (distance(f.centroidLps, c) <= vox) {
                    ++found;
                    const double tv = v.at("volume_mm3").get<double>();
                    if (v.at("equivalent_diameter_mm").get<double>() >= 4 * vox)
                        worstVolume = std::max(worstVolume, std::abs(f.volumeMm3 - tv) / tv);
                    kindsRight += f.kind == (v.at("kind") == "crack" ? "crack" : "pore");
                    if (internal <= 40)
                        std::printf("  void %-3d %-5s truth %.4f mm3 (eqd %.1f vox) | measured %.4f mm3 (%+.1f%%), thresholded "
                                    "voxel count %+.1f%%, sphericity %.2f, extent %.2f vs %.2f mm\n",
                                    f.id, f.kind.c_str(), tv, v.at("equivalent_diameter_mm").get<double>() / vox,
                                    f.volumeMm3, 100 * (f.volumeMm3 / tv - 1), 100 * (f.voxels * vox * vox * vox / tv - 1),
                                    f.sphericity, f.maxExtentMm, v.at("max_extent_mm").get<double>());
                    break;
                }
        }
        std::printf("  truth: %d of %d internal voids found (centroid within 1 voxel), %d kinds right, worst volume "
                    "error %.2f%% (voids >= 4 voxels across); porosity truth %.5f%%, difference %.5f percentage points\n",
                    found, internal, kindsRight, 100 * worstVolume, t.at("porosity_percent").get<double>(),
                    a.porosityPercent - t.at("porosity_percent").get<double>());
    }
    return 0;
}

} // namespace

int main(int argc, char** argv)
{
    openvdb::initialize();
    try {
        const std::string mode = argc > 1 ? argv[1] : "";
        if (mode == "phantom" && argc >= 4) return phantom(std::stoi(argv[2]), argv[3], argc > 4 ? argv[4] : "");
        if (mode == "analyse" && argc >= 3) return analyse(argv[2], argc > 3 ? argv[3] : "");
    } catch (const std::exception& e) {
        std::cerr << "part_bench: error: " << e.what() << "\n";
        return 1;
    }
    std::cerr << "usage: part_bench phantom N OUT.nii [TRUTH.json] | part_bench analyse CT [TRUTH.json]\n";
    return 2;
}
