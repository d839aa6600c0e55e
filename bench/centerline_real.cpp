// centerline_real: the centerline of a real colon against its published reference path
// (to catch shortcuts between loops), with the figures the test and the bench table use and
// where the worst jump along the reference lies.
//
//   centerline_real --sdf LUMEN.vdb --ref reference_path.json [--wall-penalty P] [--no-sections]
//                   [--dump OUT.json]
//
// LUMEN.vdb is a study's lumen.vdb (grid "lumen_sdf", after contact cutting), e.g. from
// `flyover run --mask large_intestine.nii.gz --study S --until segment`. Prints: path length,
// length ratio against the reference from its anus to the reference point nearest the path's
// end, mean / p95 distance to the reference, the largest jump of the nearest reference arc
// between consecutive path points, and around that jump the path's arc, radius (D), error and
// reference arc, and the reference's own route between the two arcs with the lumen depth along
// it. --dump writes the path (position, radius, nearest reference arc and error) and the depth
// along the reference path as JSON for plotting.
#include "colon/centerline.h"
#include "colon/path_compare.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

using namespace flyover;

namespace {

int usage()
{
    std::cerr << "usage: centerline_real --sdf LUMEN.vdb --ref reference_path.json [--wall-penalty P] "
                 "[--no-sections] [--dump OUT.json]\n";
    return 2;
}

} // namespace

int main(int argc, char** argv)
{
    std::string sdfPath, refPath, dumpPath;
    CenterlineParams params;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--no-sections") {
            params.centerSections = false;
            continue;
        }
        if (i + 1 >= argc) return usage();
        if (a == "--sdf") sdfPath = argv[++i];
        else if (a == "--ref") refPath = argv[++i];
        else if (a == "--dump") dumpPath = argv[++i];
        else if (a == "--wall-penalty") params.wallPenalty = std::stod(argv[++i]);
        else return usage();
    }
    if (sdfPath.empty() || refPath.empty()) return usage();
    try {
        openvdb::initialize();
        openvdb::io::File file(sdfPath);
        file.open();
        auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("lumen_sdf"));
        file.close();
        if (!sdf) throw std::runtime_error(sdfPath + ": no float grid lumen_sdf");

        std::ifstream refFile(refPath);
        const nlohmann::json ref = nlohmann::json::parse(refFile);
        std::vector<Vec3d> refPts;
        for (const auto& p : ref.at("position_mm"))
            refPts.push_back({p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()});

        const std::vector<double> refArc = arcLengthsMm(refPts);

        const auto t0 = std::chrono::steady_clock::now();
        CenterlineReport report;
        const Centerline cl = extractCenterline(*sdf, params, nullptr, &report);
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

        std::vector<Vec3d> pathPts;
        for (const CenterlinePoint& p : cl.points) pathPts.push_back(p.positionMm);
        const PathComparison cmp = comparePathToReference(pathPts, refPts);
        const std::vector<double>& err = cmp.errorMm;
        const std::vector<double>& arc = cmp.referenceArcMm;
        const double mean = cmp.meanErrorMm, p95 = cmp.p95ErrorMm, worst = cmp.worstJumpMm;
        const std::size_t jumpAt = std::max<std::size_t>(cmp.worstJumpAt, 1);
        const double refLength = arc.back() - arc.front();
        std::printf("centerline %.1f s; path %.1f mm, reference over the same stretch %.1f mm (ratio %.3f), "
                    "arc %.1f -> %.1f; error mean %.2f p95 %.2f mm; worst jump %.1f mm at path arc %.1f "
                    "(reference %.1f -> %.1f); %zu near-wall stretches, %zu bridges\n",
                    seconds, cl.lengthMm(), refLength, cl.lengthMm() / refLength, arc.front(), arc.back(),
                    mean, p95, worst, double(jumpAt) * cl.stepMm, arc[jumpAt - 1], arc[jumpAt],
                    report.nearWall.size(), report.bridges.size());
        for (const CenterlineNearWall& w : report.nearWall)
            std::printf("  near wall: arc %.1f-%.1f mm, min D %.2f mm at (%.1f, %.1f, %.1f)\n", w.fromArcMm,
                        w.toArcMm, w.minRadiusMm, w.positionMm.x, w.positionMm.y, w.positionMm.z);
        // Every jump over 10 mm.
        for (std::size_t i = 1; i < arc.size(); ++i)
            if (std::abs(arc[i] - arc[i - 1]) > 10.0)
                std::printf("  jump %.1f mm at path arc %.1f: reference %.1f -> %.1f\n",
                            std::abs(arc[i] - arc[i - 1]), double(i) * cl.stepMm, arc[i - 1], arc[i]);

        openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(*sdf);
        auto depth = [&](const Vec3d& p) { return -double(sampler.wsSample(openvdb::Vec3d(p.x, p.y, p.z))); };
        std::printf("path around the jump (arc, D, error, reference arc, position):\n");
        const long lo = std::max(0L, long(jumpAt) - 30), hi = std::min(long(arc.size()) - 1, long(jumpAt) + 30);
        for (long i = lo; i <= hi; i += 2)
            std::printf("  %7.1f %5.2f %5.2f %7.1f  (%.1f, %.1f, %.1f)\n", double(i) * cl.stepMm,
                        cl.points[i].radiusMm, err[i], arc[i], cl.points[i].positionMm.x,
                        cl.points[i].positionMm.y, cl.points[i].positionMm.z);
        std::printf("reference between the jump's arcs (arc, D, distance to the path, position):\n");
        const double a0 = std::min(arc[jumpAt - 1], arc[jumpAt]) - 10, a1 = std::max(arc[jumpAt - 1], arc[jumpAt]) + 10;
        double lastPrinted = -1e9;
        for (std::size_t i = 0; i < refPts.size(); ++i) {
            if (refArc[i] < a0 || refArc[i] > a1 || refArc[i] - lastPrinted < 2.0) continue;
            lastPrinted = refArc[i];
            double dPath = 1e9;
            for (const CenterlinePoint& p : cl.points) dPath = std::min(dPath, distance(p.positionMm, refPts[i]));
            std::printf("  %7.1f %5.2f %6.2f  (%.1f, %.1f, %.1f)\n", refArc[i], depth(refPts[i]), dPath,
                        refPts[i].x, refPts[i].y, refPts[i].z);
        }
        if (!dumpPath.empty()) {
            nlohmann::json out;
            for (std::size_t i = 0; i < cl.points.size(); ++i) {
                const Vec3d& p = cl.points[i].positionMm;
                out["path"].push_back({{"arc", double(i) * cl.stepMm}, {"p", {p.x, p.y, p.z}},
                                       {"r", cl.points[i].radiusMm}, {"err", err[i]}, {"ref_arc", arc[i]}});
            }
            for (std::size_t i = 0; i < refPts.size(); ++i)
                out["ref"].push_back({{"arc", refArc[i]}, {"d", depth(refPts[i])}});
            std::ofstream(dumpPath) << out.dump();
        }
    } catch (const std::exception& e) {
        std::cerr << "centerline_real: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
