// itk_reference: the plain reference for the first-pair time target — read a CT with ITK,
// threshold it, mesh the threshold — timed on the same file as `flyover run`, so that
// bench/first_pair.sh can print the ratio CT -> first pair / reference.
//
//   itk_reference CT.nii[.gz] [--lower HU] [--upper HU] [--runs N] [--mesher vdb|itk]
//
// Steps: itk::ImageFileReader<short> with itk::NiftiImageIO (the voxels inflated and converted
// by ITK), itk::BinaryThresholdImageFilter (HU in [lower, upper] -> 1, default [-1100, -500]:
// air), and OpenVDB's marching cubes (tools::volumeToMesh, iso 0.5) of the mask copied into a
// sparse float grid (tools::copyFromDense). No segmentation, no centerline, no rendering: the
// least any viewer of the same file does before it can show a surface. `--mesher itk` meshes
// with ITK's own marching cubes instead (itk::BinaryMask3DMeshSource into an itk::Mesh, one
// thread): the pipeline made of ITK alone, slower than the default ITK read + OpenVDB mesh. Prints per step the
// wall and CPU (user + system) seconds of the median run, the mesh size, and one line
// "reference_seconds S" (the median wall time of the whole) that first_pair.sh reads.
#include <itkBinaryMask3DMeshSource.h>
#include <itkBinaryThresholdImageFilter.h>
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkMesh.h>
#include <itkNiftiImageIO.h>

#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <vector>

namespace {

double cpuSeconds()
{
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

double wallSeconds()
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

struct Step {
    double wall = 0, cpu = 0;
};

struct Run {
    Step read, threshold, grid, mesh;
    double total = 0;
    std::size_t points = 0, quads = 0, triangles = 0;
};

Run runOnce(const std::string& path, short lower, short upper, bool itkMesher)
{
    using CtImage = itk::Image<short, 3>;
    using MaskImage = itk::Image<unsigned char, 3>;
    Run r;
    const double w0 = wallSeconds(), c0 = cpuSeconds();
    auto mark = [](Step& s, double& w, double& c) {
        const double w1 = wallSeconds(), c1 = cpuSeconds();
        s.wall = w1 - w;
        s.cpu = c1 - c;
        w = w1;
        c = c1;
    };
    double w = w0, c = c0;

    auto reader = itk::ImageFileReader<CtImage>::New();
    reader->SetImageIO(itk::NiftiImageIO::New());
    reader->SetFileName(path);
    reader->Update();
    mark(r.read, w, c);

    auto threshold = itk::BinaryThresholdImageFilter<CtImage, MaskImage>::New();
    threshold->SetInput(reader->GetOutput());
    threshold->SetLowerThreshold(lower);
    threshold->SetUpperThreshold(upper);
    threshold->SetInsideValue(1);
    threshold->SetOutsideValue(0);
    threshold->Update();
    MaskImage::Pointer mask = threshold->GetOutput();
    mask->DisconnectPipeline();
    reader = nullptr;
    threshold = nullptr;
    mark(r.threshold, w, c);

    if (itkMesher) {
        using MeshType = itk::Mesh<double, 3>;
        auto mesher = itk::BinaryMask3DMeshSource<MaskImage, MeshType>::New();
        mesher->SetInput(mask);
        mesher->SetObjectValue(1);
        mesher->Update();
        r.points = mesher->GetNumberOfNodes();
        r.triangles = mesher->GetNumberOfCells();
        mask = nullptr;
        mark(r.mesh, w, c);
        r.total = w - w0;
        return r;
    }
    // ITK's buffer is x fastest: OpenVDB's LayoutXYZ.
    const auto size = mask->GetLargestPossibleRegion().GetSize();
    const openvdb::CoordBBox box(openvdb::Coord(0), openvdb::Coord(int(size[0]) - 1, int(size[1]) - 1, int(size[2]) - 1));
    openvdb::tools::Dense<unsigned char, openvdb::tools::LayoutXYZ> dense(box, mask->GetBufferPointer());
    auto grid = openvdb::FloatGrid::create(0.0f);
    openvdb::tools::copyFromDense(dense, *grid, 0.0f);
    const auto spacing = mask->GetSpacing();
    openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
    for (int i = 0; i < 3; ++i) m(i, i) = spacing[unsigned(i)];
    grid->setTransform(openvdb::math::Transform::createLinearTransform(m));
    mask = nullptr;
    mark(r.grid, w, c);

    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*grid, points, triangles, quads, 0.5);
    mark(r.mesh, w, c);
    r.total = w - w0;
    r.points = points.size();
    r.quads = quads.size();
    r.triangles = triangles.size();
    return r;
}

} // namespace

int main(int argc, char** argv)
{
    std::string path;
    short lower = -1100, upper = -500;
    int runs = 1;
    bool itkMesher = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "itk_reference: %s needs a value\n", a.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--lower") lower = short(std::stoi(next()));
        else if (a == "--upper") upper = short(std::stoi(next()));
        else if (a == "--runs") runs = std::max(1, std::stoi(next()));
        else if (a == "--mesher") {
            const std::string m = next();
            if (m != "vdb" && m != "itk") {
                std::fprintf(stderr, "itk_reference: --mesher must be vdb or itk, got '%s'\n", m.c_str());
                return 2;
            }
            itkMesher = m == "itk";
        }
        else if (!a.empty() && a[0] == '-') {
            std::fprintf(stderr, "itk_reference: unknown option %s\n", a.c_str());
            return 2;
        } else path = a;
    }
    if (path.empty()) {
        std::fprintf(stderr, "usage: itk_reference CT.nii[.gz] [--lower HU] [--upper HU] [--runs N] [--mesher vdb|itk]\n");
        return 2;
    }
    openvdb::initialize();
    std::vector<Run> all;
    try {
        for (int i = 0; i < runs; ++i) all.push_back(runOnce(path, lower, upper, itkMesher));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "itk_reference: %s: %s\n", path.c_str(), e.what());
        return 1;
    }
    std::sort(all.begin(), all.end(), [](const Run& a, const Run& b) { return a.total < b.total; });
    const Run& r = all[all.size() / 2];
    std::printf("ITK read + threshold [%d, %d] HU + marching cubes (%s) of %s (median of %d)\n", lower, upper,
                itkMesher ? "ITK" : "OpenVDB", path.c_str(), runs);
    std::printf("  read (ITK NiftiImageIO)      %7.3f s wall %7.3f s CPU\n", r.read.wall, r.read.cpu);
    std::printf("  BinaryThresholdImageFilter   %7.3f s wall %7.3f s CPU\n", r.threshold.wall, r.threshold.cpu);
    if (itkMesher) {
        std::printf("  BinaryMask3DMeshSource       %7.3f s wall %7.3f s CPU  (%zu points, %zu triangles)\n",
                    r.mesh.wall, r.mesh.cpu, r.points, r.triangles);
    } else {
        std::printf("  copyFromDense (sparse grid)  %7.3f s wall %7.3f s CPU\n", r.grid.wall, r.grid.cpu);
        std::printf("  volumeToMesh (iso 0.5)       %7.3f s wall %7.3f s CPU  (%zu points, %zu quads, %zu triangles)\n",
                    r.mesh.wall, r.mesh.cpu, r.points, r.quads, r.triangles);
    }
    std::printf("reference_seconds %.3f\n", r.total);
    return 0;
}
