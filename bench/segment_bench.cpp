// segment_bench: lumen segmentation (colon/segment.h) on a phantom's HU grid, against a
// plain pass over the same grid (air threshold + face-connected components), as a ratio.
// With --mask: the mask-only path (colon/lumen_mask.h, segmentFromMask) on the phantom's true
// lumen mask written as .nii.gz (read from the file, as `flyover run --mask` does), with the
// time of each step.
//
//   segment_bench [--size full|medium|small] [--runs N] [--fluid] [--collapse] [--seed N]
//                 [--touching N] [--redundant] [--rectal-tube] [--spacing SX,SY,SZ] [--ct FILE]
//                 [--mask | --centerline] [--mask-file FILE [--contacts]] [--lumen-file FILE]
//
// The phantom options are those of `flyover phantom`; --ct FILE ingests that CT (any format
// openImage() reads, e.g. one written by `flyover phantom`) instead of generating a phantom.
//
// --centerline: instead, segment + centerline as before contacts were cut ("centerline") against
// segment + contact cutting + centerline ("contacts", colon/contacts.h), time and peak memory.
//
// --mask-file FILE: the mask-only path on that mask file (e.g. a real segmentation) instead of a
// phantom's; with --contacts, followed by cutContacts (colon/contacts.h), each step timed.
//
// --lumen-file FILE: cutContacts alone, each step timed, on a copy of the `lumen_sdf` and
// `lumen_mask` grids of FILE (a study's lumen.vdb written with
// `--set segment.cut_contacts=false`), with a digest of the cut grids and the contacts (the
// same digest from two builds: the same cuts).
//
// The phantom is generated and ingested once and saved as a temporary .vdb; each measured
// pass then runs in a fresh child process (this program with --grid FILE --mode MODE) that
// loads only the grid, so that its peak resident memory is that of the pass plus the grid,
// not of the phantom generator. Prints the median and range of the wall times of N runs, the
// median CPU time (user + system: steadier than wall time on a shared machine), and each
// child's resident memory after loading and at its peak.
#include "bench/process_memory.h"
#include "colon/phantom.h"
#include "volume/image_io.h"
#include "colon/centerline.h"
#include "colon/contacts.h"
#include "volume/ingest.h"
#include "colon/lumen_mask.h"
#include "colon/segment.h"
#include "volume/mask_components.h"
#include "volume/segment_tools.h"

#include <openvdb/openvdb.h>
#include <openvdb/tree/LeafManager.h>

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
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

using bench::currentRssMb;
using bench::peakRssMb;

/// User + system CPU time of this process so far (s).
double cpuSeconds()
{
    rusage usage{};
    ::getrusage(RUSAGE_SELF, &usage);
    return double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
           1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

/// The plain pass: air candidates below -800 HU among the active voxels, then components.
std::size_t thresholdAndComponents(const openvdb::FloatGrid& hu)
{
    auto air = std::make_shared<openvdb::BoolTree>(hu.tree(), false, true, openvdb::TopologyCopy());
    openvdb::tree::LeafManager<openvdb::BoolTree> leaves(*air);
    leaves.foreach([&](openvdb::BoolTree::LeafNodeType& leaf, std::size_t) {
        const auto* src = hu.tree().probeConstLeaf(leaf.origin());
        for (auto it = src->cbeginValueOn(); it; ++it)
            if (!(*it < -800.0f)) leaf.setValueOff(it.pos(), false);
    });
    detail::pruneInactive(*air);
    return connectedComponents(*air).size();
}

/// Wall and CPU time (user + system, all threads: steadier on a shared machine) of each step
/// that the segmentation reports, summed over the runs.
struct StepTimes : Progress {
    struct Step {
        std::string name;
        double wall = 0, cpu = 0;
    };
    std::vector<Step> steps;
    std::chrono::steady_clock::time_point last = std::chrono::steady_clock::now();
    double lastCpu = cpuSeconds();
    std::string current = "start";
    void update(double, const std::string& what) override
    {
        if (what == current) return;  // the same step reporting its progress
        const auto now = std::chrono::steady_clock::now();
        const double c = cpuSeconds();
        const double s = std::chrono::duration<double>(now - last).count();
        auto it = std::find_if(steps.begin(), steps.end(), [&](const Step& p) { return p.name == current; });
        if (it == steps.end()) steps.push_back({current, s, c - lastCpu});
        else {
            it->wall += s;
            it->cpu += c - lastCpu;
        }
        last = now;
        lastCpu = c;
        current = what;
    }
    void start()
    {
        last = std::chrono::steady_clock::now();
        lastCpu = cpuSeconds();
        current = "start";
    }
    void print(int runs) const
    {
        for (const Step& st : steps)
            std::printf("#   %-28s wall %.3f s, CPU %.3f s (mean of %d runs)\n", (st.name + ":").c_str(), st.wall / runs,
                        st.cpu / runs, runs);
    }
};

/// The child's result line (parsed by the parent): the median, min and max wall seconds of the
/// runs, their median CPU seconds, the memory after loading and at the peak, and `what`; after
/// the per-step means. Returns 0, the child's exit status.
int printChildResult(const char* label, std::vector<double> seconds, std::vector<double> cpu, const StepTimes& steps,
                     int runs, double loadedMb, const std::string& what)
{
    std::sort(seconds.begin(), seconds.end());
    std::sort(cpu.begin(), cpu.end());
    steps.print(runs);
    std::printf("%s %.3f %.3f %.3f %.3f %.0f %.0f %s\n", label, seconds[seconds.size() / 2], seconds.front(),
                seconds.back(), cpu[cpu.size() / 2], loadedMb, peakRssMb(), what.c_str());
    return 0;
}

int maskChild(const std::string& maskPath, int runs, bool contacts)
{
    openvdb::initialize();
    const double loadedMb = currentRssMb();
    std::vector<double> seconds, cpu;
    std::string what;
    StepTimes steps;
    for (int r = 0; r < runs; ++r) {
        const double c0 = cpuSeconds();
        const auto t0 = std::chrono::steady_clock::now();
        steps.start();
        auto source = openImage(maskPath);
        LumenSegmentation seg = segmentFromMask(*source, SegmentParams{}, nullptr, &steps);
        std::ostringstream s;
        s << seg.pieces.size() << " piece(s), lumen " << seg.lumenVolumeMl << " mL, mask " << seg.maskVolumeMl
          << " mL, rectal tube " << (seg.rectalTube.found ? "found" : "none");
        if (contacts) {
            const ContactReport cr = cutContacts(*seg.sdf, seg.mask.get(), ContactParams{}, &steps);
            std::size_t cut = 0;
            for (const ContactInfo& c : cr.contacts) cut += c.cut;
            s << ", " << cr.regions << " regions, " << cr.links << " links, " << cut << " contact(s) cut";
        }
        steps.update(1.0, "end");
        what = s.str();
        seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        cpu.push_back(cpuSeconds() - c0);
    }
    return printChildResult("mask", seconds, cpu, steps, runs, loadedMb, what);
}

/// FNV-1a over the active voxels (coordinates and values, in tree order) of a grid.
template<typename GridT>
std::uint64_t gridDigest(const GridT& grid, std::uint64_t h = 1469598103934665603ull)
{
    auto add = [&h](const void* p, std::size_t bytes) {
        const auto* c = static_cast<const unsigned char*>(p);
        for (std::size_t i = 0; i < bytes; ++i) h = (h ^ c[i]) * 1099511628211ull;
    };
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        const auto v = *it;
        add(&c, sizeof c);
        add(&v, sizeof v);
    }
    return h;
}

int lumenChild(const std::string& lumenPath, int runs)
{
    openvdb::initialize();
    openvdb::io::File file(lumenPath);
    file.open();
    const auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("lumen_sdf"));
    const auto mask = openvdb::gridPtrCast<openvdb::BoolGrid>(file.readGrid("lumen_mask"));
    file.close();
    if (!sdf || !mask) throw std::runtime_error(lumenPath + ": lumen_sdf or lumen_mask missing or of another type");
    const double loadedMb = currentRssMb();
    std::vector<double> seconds, cpu;
    std::string what;
    StepTimes steps;
    for (int r = 0; r < runs; ++r) {
        const auto s = sdf->deepCopy();
        const auto m = mask->deepCopy();
        const double c0 = cpuSeconds();
        const auto t0 = std::chrono::steady_clock::now();
        steps.start();
        const ContactReport cr = cutContacts(*s, m.get(), ContactParams{}, &steps);
        steps.update(1.0, "end");
        seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        cpu.push_back(cpuSeconds() - c0);
        std::size_t cut = 0;
        std::ostringstream o;
        o.precision(17);
        for (const ContactInfo& c : cr.contacts) {
            cut += c.cut;
            o << c.positionMm.x << ',' << c.positionMm.y << ',' << c.positionMm.z << ',' << c.widthMm << ','
              << c.voxelsRemoved << ',' << c.links << ',' << c.cut << ',' << c.detourMm << ';';
        }
        const std::string contacts = o.str();
        std::uint64_t h = gridDigest(*m, gridDigest(*s));
        for (char ch : contacts) h = (h ^ static_cast<unsigned char>(ch)) * 1099511628211ull;
        std::ostringstream w;
        w << cr.regions << " regions, " << cr.links << " links, " << cr.cycleLinks << " cycle links, "
          << cr.wideCycles << " wide cycles, " << cut << " of " << cr.contacts.size() << " contact(s) cut, digest "
          << std::hex << h;
        what = w.str();
    }
    return printChildResult("contacts", seconds, cpu, steps, runs, loadedMb, what);
}

int child(const std::string& gridPath, const std::string& mode, int runs)
{
    if (mode == "lumencontacts") return lumenChild(gridPath, runs);
    if (mode == "mask" || mode == "maskcontacts") return maskChild(gridPath, runs, mode == "maskcontacts");
    openvdb::initialize();
    openvdb::io::File file(gridPath);
    file.open();
    const auto hu = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("ct_hu"));
    file.close();
    const double loadedMb = currentRssMb();
    std::vector<double> seconds, cpu;
    std::string what;
    StepTimes steps;
    for (int r = 0; r < runs; ++r) {
        const double c0 = cpuSeconds();
        const auto t0 = std::chrono::steady_clock::now();
        if (mode == "segment") {
            steps.start();
            const LumenSegmentation seg = segmentLumen(*hu, SegmentParams{}, &steps);
            std::ostringstream s;
            s << seg.pieces.size() << " piece(s), lumen " << seg.lumenVolumeMl << " mL, fluid "
              << seg.fluidVolumeMl << " mL";
            what = s.str();
        } else if (mode == "centerline" || mode == "contacts") {
            steps.last = t0;
            steps.current = "start";
            LumenSegmentation seg = segmentLumen(*hu, SegmentParams{}, &steps);
            ContactParams cp;
            cp.enabled = mode == "contacts";
            const ContactReport cr = cutContacts(*seg.sdf, seg.mask.get(), cp, &steps);
            const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{}, &steps);
            std::size_t cut = 0;
            for (const ContactInfo& c : cr.contacts) cut += c.cut;
            std::ostringstream s;
            s << " path " << cl.lengthMm() << " mm, " << cut << " contact(s) cut";
            what = s.str();
        } else {
            what = std::to_string(thresholdAndComponents(*hu)) + " air components";
        }
        seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        cpu.push_back(cpuSeconds() - c0);
    }
    return printChildResult(mode.c_str(), seconds, cpu, steps, runs, loadedMb, what);
}

struct Measure {
    double median = 0, min = 0, max = 0, cpuMedian = 0, loadedMb = 0, peakMb = 0;
    std::string what;
};

Measure runChild(const std::string& self, const std::string& grid, const std::string& mode, int runs)
{
    const std::string cmd = "'" + self + "' --grid '" + grid + "' --mode " + mode + " --runs " + std::to_string(runs);
    FILE* pipe = ::popen(cmd.c_str(), "r");
    if (!pipe) throw std::runtime_error("cannot run " + cmd);
    char buffer[1024];
    std::string out;
    while (std::fgets(buffer, sizeof buffer, pipe)) out += buffer;
    if (::pclose(pipe) != 0) throw std::runtime_error(cmd + " failed:\n" + out);
    // Step lines (starting with '#') first, then one line of figures.
    std::string figures, line;
    std::istringstream lines(out);
    while (std::getline(lines, line)) {
        if (line.rfind("#", 0) == 0) std::printf("%s\n", line.c_str() + 1);
        else if (!line.empty()) figures = line;
    }
    std::istringstream in(figures);
    Measure m;
    std::string name;
    in >> name >> m.median >> m.min >> m.max >> m.cpuMedian >> m.loadedMb >> m.peakMb;
    std::getline(in, m.what);
    return m;
}

/// --mask: the phantom's true lumen written as a mask file, segmentFromMask on it in a child.
int benchPhantomMask(const PhantomParams& pp, const std::string& variant, int runs)
{
    const auto t0 = std::chrono::steady_clock::now();
    const fs::path maskPath = fs::temp_directory_path() / ("segment_bench_" + std::to_string(::getpid()) + "_mask.nii.gz");
    {
        Phantom ph = makePhantom(pp);
        writeImage(ph.truthLumen, maskPath.string());
        const auto& g = ph.truthLumen.geometry;
        std::printf("phantom %s true lumen mask: %lld x %lld x %lld at %.3g x %.3g x %.3g mm, truth lumen "
                    "%.1f mL (built in %.1f s)\n",
                    variant.c_str(), (long long)g.size[0], (long long)g.size[1], (long long)g.size[2], g.spacingMm.x,
                    g.spacingMm.y, g.spacingMm.z, ph.truth.lumenVolumeMl,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    const std::string self = fs::read_symlink("/proc/self/exe").string();
    const Measure m = runChild(self, maskPath.string(), "mask", runs);
    fs::remove(maskPath);
    std::printf("%-24s: wall median %.3f s (%.3f..%.3f, %d runs), CPU median %.3f s; RSS peak %.0f MB;%s\n",
                "segmentFromMask (file)", m.median, m.min, m.max, runs, m.cpuMedian, m.peakMb, m.what.c_str());
    return 0;
}

} // namespace

int main(int argc, char** argv)
{
    std::string size = "full", grid, mode;
    int runs = 5;
    bool fluid = false, collapse = false, mask = false, centerline = false, contacts = false;
    std::string maskFile, lumenFile;
    PhantomParams pp;
    std::string ctPath, spacingText;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--size" && i + 1 < argc) size = argv[++i];
        else if (a == "--runs" && i + 1 < argc) runs = std::max(1, std::atoi(argv[++i]));
        else if (a == "--grid" && i + 1 < argc) grid = argv[++i];
        else if (a == "--mode" && i + 1 < argc) mode = argv[++i];
        else if (a == "--fluid") fluid = true;
        else if (a == "--collapse") collapse = true;
        else if (a == "--mask") mask = true;
        else if (a == "--centerline") centerline = true;
        else if (a == "--mask-file" && i + 1 < argc) maskFile = argv[++i];
        else if (a == "--contacts") contacts = true;
        else if (a == "--lumen-file" && i + 1 < argc) lumenFile = argv[++i];
        else if (a == "--seed" && i + 1 < argc) pp.seed = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--touching" && i + 1 < argc) pp.touching = std::atoi(argv[++i]);
        else if (a == "--redundant") pp.redundant = true;
        else if (a == "--rectal-tube") pp.rectalTube = true;
        else if (a == "--spacing" && i + 1 < argc) spacingText = argv[++i];
        else if (a == "--ct" && i + 1 < argc) ctPath = argv[++i];
        else {
            std::cerr << "usage: segment_bench [--size full|medium|small] [--runs N] [--fluid] [--collapse] [--seed N] "
                         "[--touching N] [--redundant] [--rectal-tube] [--spacing SX,SY,SZ] [--ct FILE] "
                         "[--mask | --centerline] [--mask-file FILE [--contacts]] [--lumen-file FILE]\n";
            return 2;
        }
    }
    if (!spacingText.empty()) {
        char tail = 0;
        if (std::sscanf(spacingText.c_str(), "%lf,%lf,%lf%c", &pp.spacingMm.x, &pp.spacingMm.y, &pp.spacingMm.z,
                        &tail) != 3 ||
            !(pp.spacingMm.x > 0 && pp.spacingMm.y > 0 && pp.spacingMm.z > 0)) {
            std::cerr << "segment_bench: --spacing wants three positive numbers SX,SY,SZ (mm), got '" << spacingText
                      << "'\n";
            return 2;
        }
    }
    if (!ctPath.empty() && mask) {
        std::cerr << "segment_bench: --ct and --mask do not go together (--mask uses the phantom's true lumen)\n";
        return 2;
    }
    try {
        if (!grid.empty()) return child(grid, mode, runs);
        if (!lumenFile.empty()) {
            const std::string self = fs::read_symlink("/proc/self/exe").string();
            const Measure m = runChild(self, lumenFile, "lumencontacts", runs);
            std::printf("%-24s: wall median %.3f s (%.3f..%.3f, %d runs), CPU median %.3f s; RSS peak %.0f MB; %s\n",
                        "cutContacts", m.median, m.min, m.max, runs, m.cpuMedian, m.peakMb, m.what.c_str());
            return 0;
        }
        if (!maskFile.empty()) {
            const std::string self = fs::read_symlink("/proc/self/exe").string();
            const Measure m = runChild(self, maskFile, contacts ? "maskcontacts" : "mask", runs);
            std::printf("%-24s: wall median %.3f s (%.3f..%.3f, %d runs), CPU median %.3f s; RSS peak %.0f MB;%s\n",
                        contacts ? "segmentFromMask+contacts" : "segmentFromMask (file)", m.median, m.min, m.max,
                        runs, m.cpuMedian, m.peakMb, m.what.c_str());
            return 0;
        }

        openvdb::initialize();
        pp.size = parsePhantomSize(size);
        pp.fluid = fluid;
        pp.collapse = collapse;
        const auto t0 = std::chrono::steady_clock::now();
        const fs::path tmp = fs::temp_directory_path() / ("segment_bench_" + std::to_string(::getpid()) + ".vdb");
        double truthMl = 0;
        std::ostringstream variant;
        variant << size << (fluid ? " --fluid" : "") << (collapse ? " --collapse" : "") << " --seed " << pp.seed;
        if (pp.touching) variant << " --touching " << pp.touching;
        if (pp.redundant) variant << " --redundant";
        if (pp.rectalTube) variant << " --rectal-tube";
        if (!spacingText.empty()) variant << " --spacing " << spacingText;
        if (mask) return benchPhantomMask(pp, variant.str(), runs);
        {
            IngestReport rep;
            openvdb::FloatGrid::Ptr hu;
            if (!ctPath.empty()) {
                auto source = openImage(ctPath);
                hu = ingestImage(*source, IngestParams{}, &rep);
                variant.str("CT file " + ctPath);
            } else {
                Phantom ph = makePhantom(pp);
                truthMl = ph.truth.lumenVolumeMl;
                Image3<float> ct;
                ct.geometry = ph.ct.geometry;
                ct.voxels.assign(ph.ct.voxels.begin(), ph.ct.voxels.end());
                ph = Phantom{};
                hu = ingestImage(ct, IngestParams{}, &rep);
            }
            hu->setName("ct_hu");
            openvdb::io::File file(tmp.string());
            file.write({hu});
            std::printf("phantom %s: %lld x %lld x %lld, HU grid %.4g mm voxels, %lld active voxels, "
                        "%.0f MB; truth lumen %.1f mL (built in %.1f s)\n",
                        variant.str().c_str(),
                        (long long)rep.inputSize[0], (long long)rep.inputSize[1], (long long)rep.inputSize[2],
                        rep.voxelMm, (long long)rep.activeVoxels, double(rep.memoryBytes) / 1e6, truthMl,
                        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        }
        const std::string self = fs::read_symlink("/proc/self/exe").string();
        if (centerline) {
            const Measure before = runChild(self, tmp.string(), "centerline", runs);
            const Measure after = runChild(self, tmp.string(), "contacts", runs);
            fs::remove(tmp);
            for (const auto& [name, m] : {std::pair<const char*, const Measure&>{"segment + centerline", before},
                                          std::pair<const char*, const Measure&>{"+ contacts", after}})
                std::printf("%-24s: wall median %.3f s (%.3f..%.3f, %d runs), CPU median %.3f s; RSS %.0f MB "
                            "after loading the grid, peak %.0f MB;%s\n",
                            name, m.median, m.min, m.max, runs, m.cpuMedian, m.loadedMb, m.peakMb, m.what.c_str());
            std::printf("%-24s: %.2f x the wall time without contacts, %.2f x its CPU time, %.2f x its peak memory\n",
                        "ratio", after.median / before.median, after.cpuMedian / before.cpuMedian,
                        after.peakMb / before.peakMb);
            return 0;
        }
        const Measure seg = runChild(self, tmp.string(), "segment", runs);
        const Measure plain = runChild(self, tmp.string(), "threshold", runs);
        fs::remove(tmp);
        for (const auto& [name, m] : {std::pair<const char*, const Measure&>{"segmentLumen", seg},
                                      std::pair<const char*, const Measure&>{"threshold + components", plain}})
            std::printf("%-24s: wall median %.3f s (%.3f..%.3f, %d runs), CPU median %.3f s; RSS %.0f MB after "
                        "loading the grid, peak %.0f MB;%s\n",
                        name, m.median, m.min, m.max, runs, m.cpuMedian, m.loadedMb, m.peakMb, m.what.c_str());
        std::printf("%-24s: %.1f x the plain pass's wall time, %.1f x its CPU time, %.2f x its peak memory\n",
                    "ratio", seg.median / plain.median, seg.cpuMedian / plain.cpuMedian, seg.peakMb / plain.peakMb);
    } catch (const std::exception& e) {
        std::cerr << "segment_bench: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
