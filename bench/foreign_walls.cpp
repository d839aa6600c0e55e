// Foreign walls in a study's fly-over views: of the wall pixels of every pose in
// frames/poses.json (both cameras, --px square), the share whose wall belongs to a part of the
// path more than --limit-mm along the colon from the pose (by the inward-normal rule of
// bench/foreign_walls.h, not by the render's own owners), under the thesis' OST and loop-local
// (owners from render/loop_ownership.h, reach --reach-mm). Reads the study; writes nothing.
//
//   foreign_walls --study DIR [--px 256] [--limit-mm 80] [--reach-mm 80]
#include "bench/foreign_walls.h"
#include "pipeline/artifact_io.h"
#include "render/loop_ownership.h"
#include "volume/error.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>

using namespace flyover;
using nlohmann::json;

namespace {


void addTo(bench::ForeignPixels& sum, const bench::ForeignPixels& add)
{
    sum.wall += add.wall;
    sum.foreign += add.foreign;
    sum.unknown += add.unknown;
}

double largest(const std::vector<double>& v) { return v.empty() ? 0.0 : *std::max_element(v.begin(), v.end()); }

double median(std::vector<double> v)
{
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

} // namespace

int main(int argc, char** argv)
{
    std::string study;
    int px = 256;
    double limitMm = 80, reachMm = 80;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::cerr << "foreign_walls: " << a << " needs a value\n";
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--study") study = next();
        else if (a == "--px") px = std::atoi(next().c_str());
        else if (a == "--limit-mm") limitMm = std::atof(next().c_str());
        else if (a == "--reach-mm") reachMm = std::atof(next().c_str());
        else {
            std::cerr << "foreign_walls: unknown option " << a << " (known: --study --px --limit-mm --reach-mm)\n";
            return 2;
        }
    }
    if (study.empty() || px < 8 || px > 4096 || !(limitMm > 0) || !(reachMm > 0)) {
        std::cerr << "usage: foreign_walls --study DIR [--px 8..4096] [--limit-mm > 0] [--reach-mm > 0]\n";
        return 2;
    }
    try {
        std::vector<float> xyz;
        std::vector<uint32_t> tris;
        if (!readPlainPly(study + "/surface.ply", xyz, tris))
            throw InputError(study + "/surface.ply: not the binary PLY layout flyover writes");
        const RayScene scene(std::move(xyz), std::move(tris));
        const Centerline cl = centerlineFromJson(readJson(study + "/centerline.json"), study + "/centerline.json");
        const json poses = readJson(study + "/frames/poses.json");
        const auto t0 = std::chrono::steady_clock::now();
        const TriangleOwners owners = triangleOwners(scene, cl);
        const double ownersSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        const std::vector<float> reference = bench::normalLineOwners(scene, cl);
        std::size_t referenceUnknown = 0;
        for (const float r : reference) referenceUnknown += std::isnan(r) ? 1 : 0;
        bench::ForeignPixels thesis, local;
        std::vector<double> thesisPose, localPose;
        for (const json& f : poses.at("frames")) {
            const double arc = f.at("arc_mm").get<double>();
            bench::ForeignPixels pt, pl;
            for (const json& c : f.at("cameras")) {
                const Camera cam = bench::cameraOfJson(c);
                const auto a = bench::foreignPixels(scene, cam, px, LoopWindow{}, reference, arc, limitMm);
                const auto b = bench::foreignPixels(scene, cam, px, LoopWindow{&owners.arcMm, arc, reachMm}, reference,
                                                    arc, limitMm);
                addTo(pt, a);
                addTo(pl, b);
            }
            thesisPose.push_back(pt.share());
            localPose.push_back(pl.share());
            addTo(thesis, pt);
            addTo(local, pl);
        }
        const json out{{"study", study},
                       {"poses", thesisPose.size()},
                       {"px", px},
                       {"limit_mm", limitMm},
                       {"reach_mm", reachMm},
                       {"triangles", scene.triangleCount()},
                       {"owners", {{"by_sight", owners.bySight}, {"by_neighbour", owners.byNeighbour},
                                   {"unowned", owners.unowned}, {"seconds", ownersSeconds}}},
                       {"reference_unknown_triangles", referenceUnknown},
                       {"thesis_ost", {{"foreign_share", thesis.share()},
                                       {"max_pose_share", largest(thesisPose)},
                                       {"median_pose_share", median(thesisPose)}}},
                       {"loop_local", {{"foreign_share", local.share()},
                                       {"max_pose_share", largest(localPose)},
                                       {"median_pose_share", median(localPose)}}}};
        std::cout << out.dump(2) << "\n";
    } catch (const std::exception& e) {
        std::cerr << "foreign_walls: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
