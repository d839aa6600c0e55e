#include "volume/ingest.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <sstream>
#include <vector>

namespace flyover {

namespace {

using LeafT = openvdb::FloatTree::LeafNodeType;
constexpr int LEAF_DIM = static_cast<int>(LeafT::DIM);  // 8

/// Trilinear sampling of a dense image at a continuous index position, clamped to the image
/// (the output grid never extends past the input's last voxel centre, so clamping only
/// guards rounding).
struct TrilinearSampler {
    const Image3<float>& img;

    float operator()(double x, double y, double z) const
    {
        const auto& s = img.geometry.size;
        auto split = [](double v, int64_t n, int64_t& i0, double& f) {
            v = std::clamp(v, 0.0, static_cast<double>(n - 1));
            i0 = std::min<int64_t>(static_cast<int64_t>(std::floor(v)), n - 1);
            f = v - static_cast<double>(i0);
            if (i0 == n - 1) f = 0.0;
        };
        int64_t i, j, k;
        double fx, fy, fz;
        split(x, s[0], i, fx);
        split(y, s[1], j, fy);
        split(z, s[2], k, fz);
        const int64_t i1 = std::min(i + 1, s[0] - 1), j1 = std::min(j + 1, s[1] - 1),
                      k1 = std::min(k + 1, s[2] - 1);
        auto v = [&](int64_t a, int64_t b, int64_t c) { return double(img.at(a, b, c)); };
        const double c00 = v(i, j, k) * (1 - fx) + v(i1, j, k) * fx;
        const double c10 = v(i, j1, k) * (1 - fx) + v(i1, j1, k) * fx;
        const double c01 = v(i, j, k1) * (1 - fx) + v(i1, j, k1) * fx;
        const double c11 = v(i, j1, k1) * (1 - fx) + v(i1, j1, k1) * fx;
        const double c0 = c00 * (1 - fy) + c10 * fy;
        const double c1 = c01 * (1 - fy) + c11 * fy;
        return static_cast<float>(c0 * (1 - fz) + c1 * fz);
    }
};

/// Marks the air outside the body in one axial slice: pixels below `airHu` connected
/// (4-connectivity) to the slice border. Per slice, so that it streams slab by slab; a body
/// cross-section always separates its inner air (colon, lungs) from the outside in-plane.
void markOutsideAir(const float* slice, int nx, int ny, float airHu, std::vector<uint8_t>& outside,
                    std::vector<int>& stack)
{
    outside.assign(static_cast<std::size_t>(nx) * ny, 0);
    stack.clear();
    auto push = [&](int x, int y) {
        const std::size_t n = static_cast<std::size_t>(y) * nx + x;
        if (!outside[n] && slice[n] < airHu) {
            outside[n] = 1;
            stack.push_back(static_cast<int>(n));
        }
    };
    for (int x = 0; x < nx; ++x) { push(x, 0); push(x, ny - 1); }
    for (int y = 0; y < ny; ++y) { push(0, y); push(nx - 1, y); }
    while (!stack.empty()) {
        const int n = stack.back();
        stack.pop_back();
        const int x = n % nx, y = n / nx;
        if (x > 0) push(x - 1, y);
        if (x + 1 < nx) push(x + 1, y);
        if (y > 0) push(x, y - 1);
        if (y + 1 < ny) push(x, y + 1);
    }
}

} // namespace

openvdb::math::Transform::Ptr makeGridTransform(const Vec3d& originMm, const Mat3d& direction,
                                                double voxelMm)
{
    // OpenVDB maps row vectors: world = (i, j, k, 1) * M, so row r of M is index axis r's
    // world step (voxelMm times column r of the direction cosines) and row 3 the origin.
    openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) m[r][c] = voxelMm * direction[c][r];
    m[3][0] = originMm.x;
    m[3][1] = originMm.y;
    m[3][2] = originMm.z;
    return openvdb::math::Transform::createLinearTransform(m);
}

openvdb::FloatGrid::Ptr ingestImage(const Image3<float>& image, const IngestParams& params,
                                    IngestReport* report, Progress* progress)
{
    const ImageGeometry& in = image.geometry;
    if (in.voxelCount() <= 0 || static_cast<int64_t>(image.voxels.size()) != in.voxelCount())
        throw InputError("ingest: the image is empty or its buffer does not match its size");
    const double minSpacing = std::min({in.spacingMm.x, in.spacingMm.y, in.spacingMm.z});
    if (!(minSpacing > 0)) throw InputError("ingest: the image spacing is not positive");
    if (!(params.voxelMm >= 0) || !std::isfinite(params.voxelMm))
        throw ParameterError("ingest.voxelMm: must be >= 0 (0 = smallest input spacing)");
    const double voxelMm = params.voxelMm > 0 ? params.voxelMm : minSpacing;

    // Output lattice: same origin (voxel (0,0,0) centre) and direction, cubic voxels, as many
    // as fit inside the input's extent of voxel centres.
    int dims[3];
    double step[3];  // input index units per output voxel, per axis
    for (int c = 0; c < 3; ++c) {
        const double extent = static_cast<double>(in.size[c] - 1) * in.spacingMm[c];
        dims[c] = static_cast<int>(std::floor(extent / voxelMm + 1e-6)) + 1;
        step[c] = voxelMm / in.spacingMm[c];
    }
    const float background = static_cast<float>(params.backgroundHu);
    auto grid = openvdb::FloatGrid::create(background);
    grid->setTransform(makeGridTransform(in.originMm, in.direction, voxelMm));
    grid->setName("ct_hu");
    grid->setGridClass(openvdb::GRID_UNKNOWN);
    grid->insertMeta("units", openvdb::StringMetadata("HU"));
    grid->insertMeta("world_frame", openvdb::StringMetadata("LPS"));

    TrilinearSampler sample{image};
    const int nx = dims[0], ny = dims[1], nz = dims[2];
    const bool identityResample = step[0] == 1.0 && step[1] == 1.0 && step[2] == 1.0;
    auto& tree = grid->tree();

    // Slab by slab (one leaf layer of 8 slices): resample, mark outside air per slice, and
    // build the leaves that hold any in-body voxel. Memory: one slab of floats plus the grid.
    const int slabs = (nz + LEAF_DIM - 1) / LEAF_DIM;
    std::vector<float> slab;
    std::vector<uint8_t> outsideSlab;
    for (int s = 0; s < slabs; ++s) {
        const int z0 = s * LEAF_DIM, z1 = std::min(nz, z0 + LEAF_DIM);
        const std::size_t sliceSize = static_cast<std::size_t>(nx) * ny;
        slab.assign(sliceSize * (z1 - z0), background);
        outsideSlab.assign(sliceSize * (z1 - z0), 1);
        tbb::parallel_for(z0, z1, [&](int z) {
            float* dst = slab.data() + sliceSize * (z - z0);
            for (int y = 0; y < ny; ++y)
                for (int x = 0; x < nx; ++x)
                    dst[static_cast<std::size_t>(y) * nx + x] =
                        identityResample ? image.at(x, y, z)
                                         : sample(x * step[0], y * step[1], z * step[2]);
            std::vector<uint8_t> outside;
            std::vector<int> stack;
            markOutsideAir(dst, nx, ny, static_cast<float>(params.outsideAirHu), outside, stack);
            std::copy(outside.begin(), outside.end(), outsideSlab.begin() + sliceSize * (z - z0));
        });

        const int bx = (nx + LEAF_DIM - 1) / LEAF_DIM, by = (ny + LEAF_DIM - 1) / LEAF_DIM;
        std::vector<LeafT*> leaves(static_cast<std::size_t>(bx) * by, nullptr);
        tbb::parallel_for(tbb::blocked_range<int>(0, bx * by), [&](const tbb::blocked_range<int>& r) {
            for (int b = r.begin(); b < r.end(); ++b) {
                const int x0 = (b % bx) * LEAF_DIM, y0 = (b / bx) * LEAF_DIM;
                LeafT* leaf = nullptr;
                for (int z = z0; z < z1; ++z)
                    for (int y = y0; y < std::min(ny, y0 + LEAF_DIM); ++y)
                        for (int x = x0; x < std::min(nx, x0 + LEAF_DIM); ++x) {
                            const std::size_t n = sliceSize * (z - z0) + static_cast<std::size_t>(y) * nx + x;
                            if (outsideSlab[n]) continue;
                            if (!leaf) leaf = new LeafT(openvdb::Coord(x0, y0, z0), background, false);
                            leaf->setValueOn(openvdb::Coord(x, y, z), slab[n]);
                        }
                leaves[b] = leaf;
            }
        });
        for (LeafT* leaf : leaves)
            if (leaf) tree.addLeaf(leaf);  // the tree takes ownership
        reportProgress(progress, double(s + 1) / slabs, "ingest: building the sparse grid");
    }

    if (report) {
        report->voxelMm = voxelMm;
        report->activeVoxels = static_cast<int64_t>(grid->activeVoxelCount());
        report->memoryBytes = static_cast<int64_t>(grid->memUsage());
        report->inputSize = in.size;
        report->inputSpacingMm = in.spacingMm;
    }
    if (grid->activeVoxelCount() == 0)
        throw InputError("ingest: every voxel is outside-body air (below " +
                         std::to_string(params.outsideAirHu) + " HU and connected to the border); "
                         "is this a CT in Hounsfield units?");
    return grid;
}

} // namespace flyover
