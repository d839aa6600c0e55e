// centerline_bench: extractCenterline on a study's lumen, timed (wall and process CPU,
// median of several runs), with the rectum hint the run would take (--rectum-mm, else the
// rectal tube's tip recorded in the grid's metadata).
//
//   centerline_bench LUMEN.vdb [runs]
//
// LUMEN.vdb: a study's lumen.vdb (grid "lumen_sdf"), e.g. from
// `flyover run PHANTOM.nii.gz --study S --until segment`.
#include "colon/centerline.h"
#include "colon/segment.h"

#include <openvdb/openvdb.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <iostream>
#include <string>
#include <vector>

using namespace flyover;

int main(int argc, char** argv)
{
    if (argc < 2 || argc > 3) {
        std::cerr << "usage: centerline_bench LUMEN.vdb [runs]\n";
        return 2;
    }
    const int runs = argc == 3 ? std::stoi(argv[2]) : 5;
    openvdb::initialize();
    openvdb::FloatGrid::Ptr sdf;
    try {
        openvdb::io::File file(argv[1]);
        file.open();
        sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("lumen_sdf"));
    } catch (const std::exception& e) {
        std::cerr << "centerline_bench: " << argv[1] << ": " << e.what() << "\n";
        return 1;
    }
    CenterlineParams params;
    if (const auto tip = sdf->getMetadata<openvdb::Vec3DMetadata>(RECTAL_TUBE_TIP_META))
        params.rectumMm = Vec3d{tip->value()[0], tip->value()[1], tip->value()[2]};
    std::vector<double> wall, cpu;
    std::size_t points = 0;
    for (int r = 0; r < runs; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        const std::clock_t c0 = std::clock();
        CenterlineReport report;
        points = extractCenterline(*sdf, params, nullptr, &report).points.size();
        cpu.push_back(double(std::clock() - c0) / CLOCKS_PER_SEC);
        wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    auto median = [](std::vector<double> v) {
        std::sort(v.begin(), v.end());
        return v[v.size() / 2];
    };
    std::printf("centerline: %zu points, wall %.3f s, cpu %.3f s (medians of %d)\n", points, median(wall),
                median(cpu), runs);
    return 0;
}
