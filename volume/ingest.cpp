#include "volume/ingest.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <vector>

namespace flyover {

namespace {

using LeafT = openvdb::FloatTree::LeafNodeType;
constexpr int LEAF_DIM = static_cast<int>(LeafT::DIM);  // 8

/// Positions closer than this (in voxels) to a lattice point are taken as on it, so that
/// resampling to the input's own lattice copies values exactly despite rounding.
constexpr double SNAP = 1e-6;

/// Where an output row or column falls in one input slice: lower index, fraction, and
/// whether it lies inside the slice at all.
struct AxisSample {
    int64_t i0 = 0, i1 = 0;
    float f = 0;
    bool inside = false;
};

/// Output positions x * voxelMm + startMm (mm along an in-plane axis, from the slice's
/// voxel 0) -> input sample positions on an axis of `n` voxels of `spacingMm`.
std::vector<AxisSample> axisSamples(int64_t count, double voxelMm, double startMm, int64_t n, double spacingMm)
{
    std::vector<AxisSample> s(static_cast<std::size_t>(count));
    for (int64_t x = 0; x < count; ++x) {
        double p = (startMm + double(x) * voxelMm) / spacingMm;
        const double r = std::round(p);
        if (std::fabs(p - r) < SNAP) p = r;
        AxisSample& a = s[static_cast<std::size_t>(x)];
        a.inside = p >= -SNAP && p <= double(n - 1) + SNAP;
        p = std::clamp(p, 0.0, double(n - 1));
        a.i0 = std::min<int64_t>(static_cast<int64_t>(std::floor(p)), n - 1);
        a.i1 = std::min<int64_t>(a.i0 + 1, n - 1);
        a.f = a.i0 == n - 1 ? 0.0f : static_cast<float>(p - double(a.i0));
    }
    return s;
}

/// Input slices [first, first + count) as float, kept across slabs so that each slice is
/// read once.
struct SliceWindow {
    int64_t first = 0, count = 0;
    std::vector<float> data;

    void cover(ImageSource& source, int64_t kLo, int64_t kHi, std::size_t perSlice)
    {
        if (kLo >= first && kLo < first + count) {
            const int64_t keep = first + count - kLo;
            std::memmove(data.data(), data.data() + perSlice * static_cast<std::size_t>(kLo - first),
                         perSlice * static_cast<std::size_t>(keep) * sizeof(float));
            count = keep;
        } else {
            count = 0;
        }
        first = kLo;
        const int64_t need = kHi - kLo + 1;
        if (data.size() < perSlice * static_cast<std::size_t>(need)) data.resize(perSlice * static_cast<std::size_t>(need));
        if (count < need)
            source.readSlices(first + count, first + need, data.data() + perSlice * static_cast<std::size_t>(count));
        count = need;
    }
    const float* slice(int64_t k, std::size_t perSlice) const
    {
        return data.data() + perSlice * static_cast<std::size_t>(k - first);
    }
};

/// What markOutsideAir leaves in a pixel of its slice mask.
constexpr uint8_t BODY = 0;     ///< not air: in the body
constexpr uint8_t OUTSIDE = 1;  ///< air outside the body, or no data
constexpr uint8_t INNER = 2;    ///< air not connected to the outside (colon, lungs): in the body

/// The first x in [x, end] whose byte is INNER, or end + 1; eight bytes at a time (only
/// INNER has bit 1 set).
inline int nextInner(const uint8_t* row, int x, int end)
{
    constexpr uint64_t BIT1 = 0x0202020202020202ull;
    while (x + 8 <= end + 1) {
        uint64_t word;
        std::memcpy(&word, row + x, 8);
        if (word & BIT1) break;
        x += 8;
    }
    while (x <= end && row[x] != INNER) ++x;
    return x;
}

/// Marks the air outside the body in one slice: pixels flagged already (OUTSIDE: no data)
/// and pixels below `airHu` connected (4-connectivity) to the slice border or to a flagged
/// pixel become OUTSIDE; the other air pixels INNER, the rest BODY. Per slice, so that it
/// streams slab by slab; a body cross-section always separates its inner air (colon, lungs)
/// from the outside in-plane. Scanline fill over the mask (air not yet reached is INNER):
/// whole runs of a row at a time, each pixel's byte visited a few times in memory order.
void markOutsideAir(const float* slice, int nx, int ny, float airHu, bool anyFlagged, uint8_t* mask,
                    std::vector<std::pair<int, int>>& seeds)
{
    const std::size_t count = static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny);
    for (std::size_t i = 0; i < count; ++i) {  // air not reached yet: INNER (branch-free: vectorised)
        const uint8_t flagged = mask[i] != 0, air = slice[i] < airHu;
        mask[i] = static_cast<uint8_t>(flagged | ((air & (flagged ^ 1)) << 1));
    }
    seeds.clear();
    for (int x = 0; x < nx; ++x) {
        seeds.emplace_back(x, 0);
        seeds.emplace_back(x, ny - 1);
    }
    for (int y = 0; y < ny; ++y) {
        seeds.emplace_back(0, y);
        seeds.emplace_back(nx - 1, y);
    }
    if (anyFlagged)  // grow from the neighbours of no-data pixels too
        for (int y = 0; y < ny; ++y)
            for (int x = 0; x < nx; ++x)
                if (mask[static_cast<std::size_t>(y) * nx + x] == OUTSIDE) {
                    if (x > 0) seeds.emplace_back(x - 1, y);
                    if (x + 1 < nx) seeds.emplace_back(x + 1, y);
                    if (y > 0) seeds.emplace_back(x, y - 1);
                    if (y + 1 < ny) seeds.emplace_back(x, y + 1);
                }
    while (!seeds.empty()) {
        const auto [sx, y] = seeds.back();
        seeds.pop_back();
        uint8_t* row = mask + static_cast<std::size_t>(y) * nx;
        if (row[sx] != INNER) continue;
        int x0 = sx, x1 = sx;
        while (x0 > 0 && row[x0 - 1] == INNER) --x0;
        while (x1 + 1 < nx && row[x1 + 1] == INNER) ++x1;
        std::fill(row + x0, row + x1 + 1, OUTSIDE);
        // One seed per run of air not yet reached in the rows above and below the span.
        for (int ny2 : {y - 1, y + 1}) {
            if (ny2 < 0 || ny2 >= ny) continue;
            const uint8_t* other = mask + static_cast<std::size_t>(ny2) * nx;
            for (int x = nextInner(other, x0, x1); x <= x1; x = nextInner(other, x, x1)) {
                seeds.emplace_back(x, ny2);
                while (x <= x1 && other[x] == INNER) ++x;
            }
        }
    }
}

Vec3d column(const Mat3d& m, int c) { return {m[0][c], m[1][c], m[2][c]}; }

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
    if (image.geometry.voxelCount() <= 0 || static_cast<int64_t>(image.voxels.size()) != image.geometry.voxelCount())
        throw InputError("ingest: the image is empty or its buffer does not match its size");
    MemoryImageSource source(image);
    return ingestImage(source, params, report, progress);
}

namespace {

/// Where the input slices lie and the output lattice that covers them. Slice k's voxel
/// (0,0), relative to slice 0, in the frame of the index axes: t along the slice normal,
/// (a, b) in-plane (regular: (0, 0, k * sz)).
struct SliceLayout {
    std::vector<double> t, a, b;
    double aMin = 0, bMin = 0;
    int64_t dims[3] = {0, 0, 0};
    Vec3d gridOrigin;
};

SliceLayout sliceLayout(ImageSource& source, double voxelMm)
{
    const ImageGeometry& in = source.geometry();
    const std::string& name = source.name();
    const double sx = in.spacingMm.x, sy = in.spacingMm.y, sz = in.spacingMm.z;
    const int64_t inX = in.size[0], inY = in.size[1], inK = in.size[2];
    const Vec3d u = column(in.direction, 0), v = column(in.direction, 1), w = column(in.direction, 2);
    SliceLayout L;
    auto& t = L.t;
    t.assign(static_cast<std::size_t>(inK), 0.0);
    L.a.assign(t.size(), 0.0);
    L.b.assign(t.size(), 0.0);
    if (source.isRegular()) {
        for (int64_t k = 0; k < inK; ++k) t[static_cast<std::size_t>(k)] = double(k) * sz;
    } else {
        const auto& origins = source.sliceOriginsMm();
        if (static_cast<int64_t>(origins.size()) != inK)
            throw InputError(name + ": slice positions do not match the slice count");
        for (std::size_t k = 0; k < t.size(); ++k) {
            const Vec3d d = origins[k] - origins[0];
            t[k] = dot(d, w);
            L.a[k] = dot(d, u);
            L.b[k] = dot(d, v);
            if (k > 0 && !(t[k] > t[k - 1]))
                throw InputError(name + ": slice positions are not increasing along the slice normal");
        }
    }
    L.aMin = *std::min_element(L.a.begin(), L.a.end());
    L.bMin = *std::min_element(L.b.begin(), L.b.end());
    const double aMax = *std::max_element(L.a.begin(), L.a.end()) + double(inX - 1) * sx;
    const double bMax = *std::max_element(L.b.begin(), L.b.end()) + double(inY - 1) * sy;

    // Output lattice: as many cubic voxels as fit inside the extent of input voxel centres.
    const double extent[3] = {aMax - L.aMin, bMax - L.bMin, t.back()};
    for (int c = 0; c < 3; ++c) {
        const double n = std::floor(extent[c] / voxelMm + 1e-6) + 1;
        if (!(n <= double(1 << 28))) {
            std::ostringstream os;
            os << "ingest.voxel_mm: " << voxelMm << " mm gives " << n << " voxels along an axis; too small";
            throw ParameterError(os.str());
        }
        L.dims[c] = static_cast<int64_t>(n);
    }
    if (L.dims[0] * L.dims[1] > (int64_t(1) << 28)) {
        std::ostringstream os;
        os << "ingest.voxel_mm: " << voxelMm << " mm gives slices of " << L.dims[0] << " x " << L.dims[1]
           << " voxels; too small";
        throw ParameterError(os.str());
    }
    L.gridOrigin = in.originMm + L.aMin * u + L.bMin * v;
    return L;
}

/// In-plane sample tables of one input slice's offset.
struct PlaneTables {
    std::vector<AxisSample> xs, ys;
    bool identity = false;  // output (x, y) is input (x, y): no in-plane interpolation
};

/// Bilinear sample of one input slice of width inX; false outside its footprint.
inline bool samplePlane(const float* src, int64_t inX, const PlaneTables& p, int x, int y, float& out)
{
    const AxisSample& ax = p.xs[static_cast<std::size_t>(x)];
    const AxisSample& ay = p.ys[static_cast<std::size_t>(y)];
    if (!ax.inside || !ay.inside) return false;
    const float* r0 = src + ay.i0 * inX;
    float lo = r0[ax.i0];
    if (ax.f != 0.0f) lo += (r0[ax.i1] - lo) * ax.f;
    if (ay.f != 0.0f) {
        const float* r1 = src + ay.i1 * inX;
        float hi = r1[ax.i0];
        if (ax.f != 0.0f) hi += (r1[ax.i1] - hi) * ax.f;
        lo += (hi - lo) * ay.f;
    }
    out = lo;
    return true;
}

/// The streaming resampler: slab by slab (one leaf layer of 8 slices) it reads the input
/// slices it needs, resamples, marks outside air per slice, and builds the leaves that hold any
/// in-body voxel.
class SlabIngest {
public:
    SlabIngest(ImageSource& source, const SliceLayout& layout, double voxelMm, const IngestParams& params);

    /// Output slab s into `tree`.
    void addSlab(int s, openvdb::FloatTree& tree);

    int slabCount() const { return (mNz + LEAF_DIM - 1) / LEAF_DIM; }
    /// Input slices copied unchanged (cubic voxels of voxel_mm).
    bool copyOnly() const { return mCopyOnly; }
    std::size_t workingBytes() const
    {
        return mWindowPeak + mSlab.capacity() * sizeof(float) + mOutsideSlab.capacity();
    }

private:
    /// The two input slices around output slice z (k and k + 1), and the weight of the upper one.
    void bracket(int z, int64_t& k, float& weight) const;
    /// Output slice z (of the slab from z0) into the slab, its no-data and outside air marked.
    void resampleSlice(int z, int z0, bool anyResampled);
    /// The slab's leaves (slices z0 to z1) that hold an in-body voxel.
    std::vector<LeafT*> slabLeaves(int z0, int z1) const;

    ImageSource& mSource;
    const SliceLayout& mL;
    const double mVoxelMm;
    const int64_t mInX, mInY, mInK;
    const int mNx, mNy, mNz;
    const std::size_t mInPerSlice, mSliceSize;
    const float mBackground, mAirHu;
    bool mSameOffsets = false, mInPlaneCopy = false, mCopyOnly = false;
    std::vector<PlaneTables> mPlanes;
    std::vector<float> mSlab;
    std::vector<uint8_t> mOutsideSlab;
    /// Each output slice's values: the input slice in the window itself when it is copied
    /// unchanged (no copy made), else its resampled values in mSlab.
    std::vector<const float*> mSliceValues;
    SliceWindow mWindow;
    std::size_t mWindowPeak = 0;
};

SlabIngest::SlabIngest(ImageSource& source, const SliceLayout& layout, double voxelMm, const IngestParams& params)
    : mSource(source), mL(layout), mVoxelMm(voxelMm), mInX(source.geometry().size[0]),
      mInY(source.geometry().size[1]), mInK(source.geometry().size[2]), mNx(static_cast<int>(layout.dims[0])),
      mNy(static_cast<int>(layout.dims[1])), mNz(static_cast<int>(layout.dims[2])),
      mInPerSlice(static_cast<std::size_t>(mInX * mInY)), mSliceSize(static_cast<std::size_t>(mNx) * mNy),
      mBackground(static_cast<float>(params.backgroundHu)), mAirHu(static_cast<float>(params.outsideAirHu)),
      mSliceValues(LEAF_DIM, nullptr)
{
    const ImageGeometry& in = source.geometry();
    const auto& a = mL.a;
    const auto& b = mL.b;
    // In-plane sample tables, one per distinct in-plane offset (one for a regular stack).
    mSameOffsets = std::all_of(a.begin(), a.end(), [&](double x) { return x == a[0]; }) &&
                   std::all_of(b.begin(), b.end(), [&](double y) { return y == b[0]; });
    mPlanes.resize(mSameOffsets ? 1 : mL.t.size());
    for (std::size_t q = 0; q < mPlanes.size(); ++q) {
        mPlanes[q].xs = axisSamples(mNx, voxelMm, mL.aMin - a[q], mInX, in.spacingMm.x);
        mPlanes[q].ys = axisSamples(mNy, voxelMm, mL.bMin - b[q], mInY, in.spacingMm.y);
        auto straight = [](const std::vector<AxisSample>& s, int64_t n) {
            if (static_cast<int64_t>(s.size()) != n) return false;
            for (std::size_t i = 0; i < s.size(); ++i)
                if (!s[i].inside || s[i].f != 0.0f || s[i].i0 != static_cast<int64_t>(i)) return false;
            return true;
        };
        mPlanes[q].identity = straight(mPlanes[q].xs, mInX) && straight(mPlanes[q].ys, mInY);
    }
    mCopyOnly = source.isRegular() && mPlanes[0].identity && voxelMm == in.spacingMm.z;
    mInPlaneCopy = mSameOffsets && mPlanes[0].identity;  // only k is resampled
}

void SlabIngest::bracket(int z, int64_t& k, float& weight) const
{
    const auto& t = mL.t;
    const double tz = double(z) * mVoxelMm;
    if (mInK == 1) {
        k = 0;
        weight = 0;
        return;
    }
    k = static_cast<int64_t>(std::upper_bound(t.begin(), t.end(), tz) - t.begin()) - 1;
    k = std::clamp<int64_t>(k, 0, mInK - 2);
    const std::size_t kk = static_cast<std::size_t>(k);
    double wgt = (tz - t[kk]) / (t[kk + 1] - t[kk]);
    wgt = std::clamp(wgt, 0.0, 1.0);
    if (wgt < SNAP) wgt = 0;
    if (wgt > 1 - SNAP) {  // exactly on slice k + 1
        wgt = 0;
        ++k;
    }
    weight = static_cast<float>(wgt);
}

void SlabIngest::resampleSlice(int z, int z0, bool anyResampled)
{
    float* dst = anyResampled ? mSlab.data() + mSliceSize * static_cast<std::size_t>(z - z0) : nullptr;
    uint8_t* noData = mOutsideSlab.data() + mSliceSize * static_cast<std::size_t>(z - z0);
    int64_t k;
    float wz;
    bracket(z, k, wz);
    bool anyNoData = false;
    const float*& values = mSliceValues[static_cast<std::size_t>(z - z0)];
    values = dst;
    if (mInPlaneCopy && wz == 0.0f) {
        values = mWindow.slice(k, mInPerSlice);  // read in place
    } else if (mInPlaneCopy) {
        const float* s0 = mWindow.slice(k, mInPerSlice);
        const float* s1 = mWindow.slice(std::min(k + 1, mInK - 1), mInPerSlice);
        for (std::size_t n = 0; n < mSliceSize; ++n) dst[n] = s0[n] + (s1[n] - s0[n]) * wz;
    } else {
        const int64_t k1 = std::min(k + 1, mInK - 1);
        const PlaneTables& p0 = mPlanes[mSameOffsets ? 0 : static_cast<std::size_t>(k)];
        const PlaneTables& p1 = mPlanes[mSameOffsets ? 0 : static_cast<std::size_t>(k1)];
        const float* s0 = mWindow.slice(k, mInPerSlice);
        const float* s1 = mWindow.slice(k1, mInPerSlice);
        for (int y = 0; y < mNy; ++y)
            for (int x = 0; x < mNx; ++x) {
                const std::size_t n = static_cast<std::size_t>(y) * mNx + x;
                float v0, v1 = 0;
                if (!samplePlane(s0, mInX, p0, x, y, v0) || (wz != 0.0f && !samplePlane(s1, mInX, p1, x, y, v1))) {
                    noData[n] = 1;  // outside the scanned stack: background, outside the body
                    anyNoData = true;
                    continue;
                }
                dst[n] = wz == 0.0f ? v0 : v0 + (v1 - v0) * wz;
            }
    }
    std::vector<std::pair<int, int>> seeds;
    markOutsideAir(values, mNx, mNy, mAirHu, anyNoData, noData, seeds);
}

// One row of leaves (8 rows of y) per task, read row by row of the slab (sequential reads from
// the slab's slices; the row's leaves, 2 KB each, stay in cache) rather than leaf by leaf (64
// strided streams per leaf). A leaf holds the slab's 8 values of an (x, y) next to each other
// (z fastest) and their 8 mask bits in one byte: each (x, y) is written at once from the 8
// slices. The same values, masks and leaves.
std::vector<LeafT*> SlabIngest::slabLeaves(int z0, int z1) const
{
    const int nx = mNx, ny = mNy;
    const int bx = (nx + LEAF_DIM - 1) / LEAF_DIM, by = (ny + LEAF_DIM - 1) / LEAF_DIM;
    std::vector<LeafT*> leaves(static_cast<std::size_t>(bx) * by, nullptr);
    const int zn = z1 - z0;
    tbb::parallel_for(tbb::blocked_range<int>(0, by), [&](const tbb::blocked_range<int>& r) {
        std::vector<float*> values(static_cast<std::size_t>(bx), nullptr);
        const float* src[LEAF_DIM];
        const uint8_t* outside[LEAF_DIM];
        for (int yb = r.begin(); yb < r.end(); ++yb) {
            LeafT** rowLeaves = leaves.data() + static_cast<std::size_t>(yb) * bx;
            std::fill(values.begin(), values.end(), nullptr);
            const int y0 = yb * LEAF_DIM, y1 = std::min(ny, y0 + LEAF_DIM);
            for (int y = y0; y < y1; ++y) {
                const std::size_t row = static_cast<std::size_t>(y) * nx;
                for (int zi = 0; zi < zn; ++zi) {
                    src[zi] = mSliceValues[static_cast<std::size_t>(zi)] + row;
                    outside[zi] = mOutsideSlab.data() + mSliceSize * static_cast<std::size_t>(zi) + row;
                }
                for (int x = 0; x < nx; ++x) {
                    unsigned bits = 0;
                    for (int zi = 0; zi < zn; ++zi) bits |= static_cast<unsigned>(outside[zi][x] != OUTSIDE) << zi;
                    if (!bits) continue;
                    const std::size_t xb = static_cast<std::size_t>(x >> 3);
                    if (!values[xb]) {
                        rowLeaves[xb] = new LeafT(openvdb::Coord(x & ~7, y0, z0), mBackground, false);
                        values[xb] = rowLeaves[xb]->buffer().data();
                    }
                    // Offset within the leaf: x slowest, z fastest (LeafNode::coordToOffset).
                    const openvdb::Index offset =
                        (static_cast<openvdb::Index>(x & 7) << 6) | (static_cast<openvdb::Index>(y & 7) << 3);
                    float* dst = values[xb] + offset;
                    for (int zi = 0; zi < zn; ++zi) dst[zi] = (bits >> zi) & 1u ? src[zi][x] : mBackground;
                    rowLeaves[xb]->getValueMask().template getWord<uint8_t>(offset >> 3) = static_cast<uint8_t>(bits);
                }
            }
        }
    });
    return leaves;
}

void SlabIngest::addSlab(int s, openvdb::FloatTree& tree)
{
    const int z0 = s * LEAF_DIM, z1 = std::min(mNz, z0 + LEAF_DIM);
    int64_t kLo, kHi;
    float unused;
    bracket(z0, kLo, unused);
    bracket(z1 - 1, kHi, unused);
    kHi = std::min(kHi + 1, mInK - 1);
    mWindow.cover(mSource, kLo, kHi, mInPerSlice);
    mWindowPeak = std::max(mWindowPeak, mWindow.data.size() * sizeof(float));

    bool anyResampled = !mInPlaneCopy;
    for (int z = z0; z < z1 && !anyResampled; ++z) {
        int64_t k;
        float wz;
        bracket(z, k, wz);
        anyResampled = wz != 0.0f;
    }
    // Resampled only between slices, every value of a resampled slice is written below: no fill
    // (8 MB a slab of the full phantom, 0.03 CPU s a run). Resampled in the plane, the voxels
    // outside the scanned stack keep the background.
    if (anyResampled && mInPlaneCopy) mSlab.resize(mSliceSize * static_cast<std::size_t>(z1 - z0));
    else if (anyResampled) mSlab.assign(mSliceSize * static_cast<std::size_t>(z1 - z0), mBackground);
    mOutsideSlab.assign(mSliceSize * static_cast<std::size_t>(z1 - z0), 0);
    tbb::parallel_for(z0, z1, [&](int z) { resampleSlice(z, z0, anyResampled); });
    for (LeafT* leaf : slabLeaves(z0, z1))
        if (leaf) tree.addLeaf(leaf);  // the tree takes ownership
}

} // namespace

openvdb::FloatGrid::Ptr ingestImage(ImageSource& source, const IngestParams& params,
                                    IngestReport* report, Progress* progress)
{
    const ImageGeometry& in = source.geometry();
    const std::string& name = source.name();
    if (in.voxelCount() <= 0) throw InputError(name + ": the image is empty");
    const double sx = in.spacingMm.x, sy = in.spacingMm.y, sz = in.spacingMm.z;
    if (!(std::min({sx, sy, sz}) > 0) || !std::isfinite(sx + sy + sz))
        throw InputError(name + ": the image spacing is not positive and finite");
    if (!(params.voxelMm >= 0) || !std::isfinite(params.voxelMm))
        throw ParameterError("ingest.voxel_mm: must be >= 0 (0 = smallest input spacing)");
    if (!std::isfinite(params.outsideAirHu) || !std::isfinite(params.backgroundHu))
        throw ParameterError("ingest.outside_air_hu and ingest.background_hu: must be finite");
    const double voxelMm = params.voxelMm > 0 ? params.voxelMm : std::min({sx, sy, sz});
    const SliceLayout layout = sliceLayout(source, voxelMm);

    auto grid = openvdb::FloatGrid::create(static_cast<float>(params.backgroundHu));
    grid->setTransform(makeGridTransform(layout.gridOrigin, in.direction, voxelMm));
    grid->setName("ct_hu");
    grid->setGridClass(openvdb::GRID_UNKNOWN);
    grid->insertMeta("units", openvdb::StringMetadata("HU"));
    grid->insertMeta("world_frame", openvdb::StringMetadata(WORLD_FRAME));

    SlabIngest slabs(source, layout, voxelMm, params);
    for (int s = 0; s < slabs.slabCount(); ++s) {
        slabs.addSlab(s, grid->tree());
        reportProgress(progress, double(s + 1) / slabs.slabCount(), "ingest: building the sparse grid");
    }

    const int64_t active = static_cast<int64_t>(grid->activeVoxelCount());
    if (report) {
        report->voxelMm = voxelMm;
        report->activeVoxels = active;
        report->memoryBytes = static_cast<int64_t>(grid->memUsage());
        report->inputSize = in.size;
        report->inputSpacingMm = in.spacingMm;
        report->inputOriginMm = in.originMm;
        report->inputDirection = in.direction;
        report->gridSize = {layout.dims[0], layout.dims[1], layout.dims[2]};
        report->gridOriginMm = layout.gridOrigin;
        report->interpolation =
            slabs.copyOnly() ? "none: the input voxels are cubic of voxel_mm, values copied"
                             : std::string("trilinear: bilinear within each input slice, linear between the two "
                                           "slices bracketing the output voxel at their true positions");
        report->source = source.description();
        report->sourceHeldBytes = source.heldBytes();
        report->workingBytes = static_cast<int64_t>(slabs.workingBytes());
        report->warnings = source.warnings();
    }
    if (active == 0)
        throw InputError(name + ": every voxel is outside-body air (below " + std::to_string(params.outsideAirHu) +
                         " HU and connected to the border); is this a CT in Hounsfield units?");
    return grid;
}

} // namespace flyover
