// detail::redistance(): first-order fast sweeping of a signed distance, computing exactly what
// openvdb::tools::sdfToSdf(f, 0, 1) computes (the same initialisation, the same Godunov update
// in the same float arithmetic, the same eight sweep directions in the same order, the same
// finalisation), several times faster and with far less memory.
//
// Why it may differ in speed but not in result: a Gauss-Seidel sweep in direction s updates each
// voxel from its three upwind neighbours (already updated in this sweep) and its three downwind
// neighbours (not yet updated). Any visiting order in which every voxel comes after its upwind
// and before its downwind neighbours therefore produces the same values, bit for bit. OpenVDB
// visits hyperplanes i +- j +- k = const, each in parallel, with per-voxel tree look-ups and a
// 64-byte mask per leaf and hyperplane (about 100 MB for a colon). Here each 8^3 leaf is swept
// in its own lexicographic order with direct array access, and the leaves run as a dependency
// graph (a leaf starts when its upwind face neighbours are done): no barrier between
// hyperplanes, no look-ups, and the result does not depend on the thread count or the schedule.
#include "volume/segment_tools.h"

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tree/LeafManager.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_for_each.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <unordered_map>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace flyover::detail {

namespace {

using openvdb::Coord;
using openvdb::FloatTree;
using FloatLeaf = FloatTree::LeafNodeType;
using LeafMask = FloatLeaf::NodeMaskType;

constexpr float FLT_BIG = std::numeric_limits<float>::max();
constexpr int DIM = int(FloatLeaf::DIM);  // 8
static_assert(DIM == 8, "leaf offsets below assume 8^3 leaves (offset = x << 6 | y << 3 | z)");
/// Offset steps of +x, +y, +z inside a leaf.
constexpr int STRIDE[3] = {DIM * DIM, DIM, 1};

/// Neighbour slot of a face neighbour: 2 * axis + (positive side ? 1 : 0).
constexpr int slot(int axis, bool positive) { return 2 * axis + (positive ? 1 : 0); }

/// The active leaves of one tree with their six face neighbours (leaf indices, -1 = none).
struct LeafGraph {
    std::vector<FloatLeaf*> leaves;
    std::vector<std::array<std::int32_t, 6>> neighbours;

    explicit LeafGraph(FloatTree& tree)
    {
        tree.getNodes(leaves);
        std::unordered_map<Coord, std::int32_t> index;
        index.reserve(leaves.size() * 2);
        for (std::size_t n = 0; n < leaves.size(); ++n) index.emplace(leaves[n]->origin(), std::int32_t(n));
        neighbours.resize(leaves.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 256),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t n = r.begin(); n != r.end(); ++n)
                for (int axis = 0; axis < 3; ++axis)
                    for (int side = 0; side < 2; ++side) {
                        Coord o = leaves[n]->origin();
                        o[axis] += side ? DIM : -DIM;
                        const auto it = index.find(o);
                        neighbours[n][std::size_t(slot(axis, side == 1))] = it == index.end() ? -1 : it->second;
                    }
        });
    }
};

/// Godunov's update of one voxel from the absolute values of its neighbours (a: -/+ x, -/+ y,
/// -/+ z), written as OpenVDB's FastSweeping::SweepingKernel::sweep() writes it, operation for
/// operation, so that the float results agree to the last bit.
inline bool godunov(float& value, const float (&nb)[6], float h, float sqrt2h)
{
    float d1 = std::min(nb[0], nb[1]), d2 = std::min(nb[2], nb[3]), d3 = std::min(nb[4], nb[5]);
    // A neighbour farther than 1000 world units is unset (+-FLT_MAX): OpenVDB's validity test.
    if (!(d1 < 1000.0f || d2 < 1000.0f || d3 < 1000.0f)) return false;
    const float sign = value >= 0.0f ? 1.0f : -1.0f;
    const float absV = std::abs(value);
    if (d2 < d1) std::swap(d1, d2);
    if (d3 < d2) std::swap(d2, d3);
    if (d2 < d1) std::swap(d1, d2);
    float update = d1 + h;
    if (update <= d2) {
        if (!(update < absV)) return false;
        value = sign * update;
        return true;
    }
    if (d2 <= sqrt2h + d1) {
        const float diff = d1 - d2;
        const float D = 2.0f * h * h - diff * diff;
        update = 0.5f * (d1 + d2 + std::sqrt(D));
        if (update > d2 && update <= d3) {
            if (!(update < absV)) return false;
            value = sign * update;
            return true;
        }
    }
    const float d123 = d1 + d2 + d3;
    const float D = d123 * d123 - 3.0f * (d1 * d1 + d2 * d2 + d3 * d3 - h * h);
    if (D >= 0.0f) {
        update = float(1.0 / 3.0) * (d123 + std::sqrt(D));
        if (update < absV) {
            value = sign * update;
            return true;
        }
    }
    return false;
}

#if defined(__SSE2__)
/// godunov() on four voxels at once (lanes; `at`: their offsets in `buf`, which must not be
/// neighbours of each other), without branches: the 1D, 2D and 3D updates are all computed with
/// the same float operations in the same order as godunov() (so the same bits; a square root
/// of a negative number gives NaN, which no comparison below accepts, as godunov() would not
/// take that branch) and the one godunov() takes is selected. Returns whether a lane changed.
inline bool godunov4(float* buf, const int (&at)[4], const int (&step)[3], float h, float sqrt2h)
{
    const __m128 absMask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
    auto load = [&](int off) { return _mm_set_ps(buf[at[3] + off], buf[at[2] + off], buf[at[1] + off], buf[at[0] + off]); };
    auto absLoad = [&](int off) { return _mm_and_ps(load(off), absMask); };
    auto select = [](__m128 c, __m128 a, __m128 b) { return _mm_or_ps(_mm_and_ps(c, a), _mm_andnot_ps(c, b)); };
    __m128 d1 = _mm_min_ps(absLoad(-step[0]), absLoad(step[0]));
    __m128 d2 = _mm_min_ps(absLoad(-step[1]), absLoad(step[1]));
    const __m128 d3in = _mm_min_ps(absLoad(-step[2]), absLoad(step[2]));
    // Sorted, as godunov()'s swaps sort them (equal values are interchangeable).
    const __m128 lo = _mm_min_ps(d1, d2), hi = _mm_max_ps(d1, d2);
    const __m128 d3 = _mm_max_ps(hi, d3in), mid = _mm_min_ps(hi, d3in);
    d1 = _mm_min_ps(lo, mid);
    d2 = _mm_max_ps(lo, mid);
    const __m128 hv = _mm_set1_ps(h);
    const __m128 valid = _mm_cmplt_ps(d1, _mm_set1_ps(1000.0f));
    const __m128 u1 = _mm_add_ps(d1, hv);
    const __m128 c1 = _mm_cmple_ps(u1, d2);
    const __m128 diff = _mm_sub_ps(d1, d2);
    const __m128 D2 = _mm_sub_ps(_mm_mul_ps(_mm_mul_ps(_mm_set1_ps(2.0f), hv), hv), _mm_mul_ps(diff, diff));
    const __m128 u2 = _mm_mul_ps(_mm_set1_ps(0.5f), _mm_add_ps(_mm_add_ps(d1, d2), _mm_sqrt_ps(D2)));
    const __m128 c2 = _mm_and_ps(_mm_cmple_ps(d2, _mm_add_ps(_mm_set1_ps(sqrt2h), d1)),
                                 _mm_and_ps(_mm_cmpgt_ps(u2, d2), _mm_cmple_ps(u2, d3)));
    const __m128 d123 = _mm_add_ps(_mm_add_ps(d1, d2), d3);
    const __m128 squares = _mm_add_ps(_mm_add_ps(_mm_mul_ps(d1, d1), _mm_mul_ps(d2, d2)), _mm_mul_ps(d3, d3));
    const __m128 D3 = _mm_sub_ps(_mm_mul_ps(d123, d123),
                                 _mm_mul_ps(_mm_set1_ps(3.0f), _mm_sub_ps(squares, _mm_mul_ps(hv, hv))));
    const __m128 u3 = _mm_mul_ps(_mm_set1_ps(float(1.0 / 3.0)), _mm_add_ps(d123, _mm_sqrt_ps(D3)));
    const __m128 c3 = _mm_cmpge_ps(D3, _mm_setzero_ps());
    const __m128 update = select(c1, u1, select(c2, u2, u3));
    const __m128 value = load(0);
    const __m128 absV = _mm_and_ps(value, absMask);
    const __m128 ok = _mm_and_ps(_mm_and_ps(valid, _mm_or_ps(c1, _mm_or_ps(c2, c3))), _mm_cmplt_ps(update, absV));
    if (_mm_movemask_ps(ok) == 0) return false;
    // sign * update: +update where value >= 0, else -update (exact negation).
    const __m128 negated = _mm_xor_ps(update, _mm_set1_ps(-0.0f));
    const __m128 signedUpdate = select(_mm_cmpge_ps(value, _mm_setzero_ps()), update, negated);
    alignas(16) float out[4];
    _mm_store_ps(out, select(ok, signedUpdate, value));
    for (int l = 0; l < 4; ++l) buf[at[l]] = out[l];  // a repeated lane writes the same value
    return true;
}
#endif

/// One sweep of one leaf in direction `dir` (bit a set: negative along axis a). The leaf's
/// values and its face neighbours' adjacent layers are copied into a padded 10^3 block first,
/// so that the update reads every neighbour at a fixed offset (missing neighbours: +FLT_MAX).
/// Returns whether any value changed.
bool sweepLeaf(float* v, const std::array<const float*, 6>& nb, const LeafMask& sweep, int dir, float h, float sqrt2h)
{
    if (sweep.isOff()) return false;
    constexpr int P = DIM + 2;
    constexpr int PS[3] = {P * P, P, 1};  // padded strides of x, y, z
    float buf[P * P * P];
    auto padded = [&](int x, int y, int z) { return (x + 1) * PS[0] + (y + 1) * PS[1] + (z + 1); };
    // Rows along z are contiguous in both layouts: the leaf and its faces are copied row by row.
    for (int x = 0; x < DIM; ++x)
        for (int y = 0; y < DIM; ++y) std::memcpy(&buf[padded(x, y, 0)], &v[(x << 6) | (y << 3)], DIM * sizeof(float));
    // The six faces (-/+ x, -/+ y, -/+ z): the neighbour's adjacent layer, or +FLT_MAX.
    auto row = [&](float* to, const float* from) {
        if (from) std::memcpy(to, from, DIM * sizeof(float));
        else std::fill(to, to + DIM, FLT_BIG);
    };
    {
        const float* lo = nb[std::size_t(slot(0, false))];
        const float* hi = nb[std::size_t(slot(0, true))];
        for (int y = 0; y < DIM; ++y) {
            row(&buf[padded(-1, y, 0)], lo ? lo + ((DIM - 1) << 6 | y << 3) : nullptr);
            row(&buf[padded(DIM, y, 0)], hi ? hi + (y << 3) : nullptr);
        }
    }
    {
        const float* lo = nb[std::size_t(slot(1, false))];
        const float* hi = nb[std::size_t(slot(1, true))];
        for (int x = 0; x < DIM; ++x) {
            row(&buf[padded(x, -1, 0)], lo ? lo + (x << 6 | (DIM - 1) << 3) : nullptr);
            row(&buf[padded(x, DIM, 0)], hi ? hi + (x << 6) : nullptr);
        }
    }
    {
        const float* lo = nb[std::size_t(slot(2, false))];
        const float* hi = nb[std::size_t(slot(2, true))];
        for (int x = 0; x < DIM; ++x)
            for (int y = 0; y < DIM; ++y) {
                buf[padded(x, y, -1)] = lo ? lo[(x << 6) | (y << 3) | (DIM - 1)] : FLT_BIG;
                buf[padded(x, y, DIM)] = hi ? hi[(x << 6) | (y << 3)] : FLT_BIG;
            }
    }
    const bool neg[3] = {(dir & 1) != 0, (dir & 2) != 0, (dir & 4) != 0};
    bool changed = false;
#if defined(__SSE2__)
    // Within a slice of x, the voxels are visited by anti-diagonals yi + zi = d (yi, zi: steps
    // along the sweep): a voxel's upwind neighbours in y and z lie on diagonal d - 1, its
    // downwind ones on d + 1, none on d. So the order keeps every voxel after its upwind and
    // before its downwind neighbours (the same values as row by row), and the voxels of one
    // diagonal, which do not read each other, are updated four at a time.
    for (int xi = 0; xi < DIM; ++xi) {
        const int x = neg[0] ? DIM - 1 - xi : xi;
        const LeafMask::Word word = sweep.getWord<LeafMask::Word>(x);  // bits y << 3 | z
        if (!word) continue;
        for (int d = 0; d < 2 * DIM - 1; ++d) {
            int voxels[DIM];
            int count = 0;
            for (int yi = std::max(0, d - (DIM - 1)); yi <= std::min(DIM - 1, d); ++yi) {
                const int zi = d - yi;
                const int y = neg[1] ? DIM - 1 - yi : yi;
                const int z = neg[2] ? DIM - 1 - zi : zi;
                if ((word >> (y * DIM + z)) & 1u) voxels[count++] = padded(x, y, z);
            }
            for (int g = 0; g < count; g += 4) {
                const int at[4] = {voxels[g], voxels[std::min(g + 1, count - 1)], voxels[std::min(g + 2, count - 1)],
                                   voxels[std::min(g + 3, count - 1)]};
                changed |= godunov4(buf, at, PS, h, sqrt2h);
            }
        }
    }
#else
    float n[6];
    for (int xi = 0; xi < DIM; ++xi) {
        const int x = neg[0] ? DIM - 1 - xi : xi;
        const LeafMask::Word word = sweep.getWord<LeafMask::Word>(x);  // bits y << 3 | z
        if (!word) continue;
        for (int yi = 0; yi < DIM; ++yi) {
            const int y = neg[1] ? DIM - 1 - yi : yi;
            const unsigned row = unsigned(word >> (y * DIM)) & 0xffu;
            if (!row) continue;
            for (int zi = 0; zi < DIM; ++zi) {
                const int z = neg[2] ? DIM - 1 - zi : zi;
                if (!((row >> z) & 1u)) continue;
                const int i = padded(x, y, z);
                n[0] = std::abs(buf[i - PS[0]]);
                n[1] = std::abs(buf[i + PS[0]]);
                n[2] = std::abs(buf[i - PS[1]]);
                n[3] = std::abs(buf[i + PS[1]]);
                n[4] = std::abs(buf[i - PS[2]]);
                n[5] = std::abs(buf[i + PS[2]]);
                changed |= godunov(buf[i], n, h, sqrt2h);
            }
        }
    }
#endif
    if (!changed) return false;
    for (int x = 0; x < DIM; ++x)
        for (int y = 0; y < DIM; ++y) std::memcpy(&v[(x << 6) | (y << 3)], &buf[padded(x, y, 0)], DIM * sizeof(float));
    return true;
}

} // namespace

namespace {

/// Step 1 for one leaf (OpenVDB's FastSweeping::InitSdf): active voxels next to a sign change
/// get their distance to the linear zero crossings, 1 / sqrt(sum over axes of 1 / d^2), and are
/// fixed; every other voxel gets +-FLT_MAX by its sign and, when active, is swept (set in
/// `mask`). `src`: the input leaf, `nb` its face neighbours' buffers (null: read `inAcc`).
void initialiseLeaf(const FloatLeaf& in, const std::array<const float*, 6>& nb,
                    openvdb::tree::ValueAccessor<const FloatTree>& inAcc, float h, float* dst, LeafMask& mask,
                    std::uint64_t& sweeping, std::uint64_t& boundary)
{
    const float* src = in.buffer().data();
    mask.setOff();
    // The input leaf with a layer of its face neighbours' values around (padded 10^3;
    // a missing neighbour: the tile or background value there), so that each voxel's
    // six neighbours lie at fixed offsets.
    constexpr int P = DIM + 2;
    constexpr int PS[3] = {P * P, P, 1};
    float pad[P * P * P];
    auto at = [](int x, int y, int z) { return (x + 1) * P * P + (y + 1) * P + (z + 1); };
    for (int x = 0; x < DIM; ++x)
        for (int y = 0; y < DIM; ++y) std::memcpy(&pad[at(x, y, 0)], &src[(x << 6) | (y << 3)], DIM * sizeof(float));
    for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
            const float* other = nb[std::size_t(slot(axis, side == 1))];
            for (int a = 0; a < DIM; ++a)
                for (int b = 0; b < DIM; ++b) {
                    int local[3];
                    local[axis] = side ? DIM : -1;
                    local[(axis + 1) % 3] = a;
                    local[(axis + 2) % 3] = b;
                    float value;
                    if (other) {
                        int from[3] = {local[0], local[1], local[2]};
                        from[axis] = side ? 0 : DIM - 1;
                        value = other[(from[0] << 6) | (from[1] << 3) | from[2]];
                    } else {
                        value = inAcc.getValue(in.origin().offsetBy(local[0], local[1], local[2]));  // a tile or the background
                    }
                    pad[at(local[0], local[1], local[2])] = value;
                }
        }
    const LeafMask& active = in.getValueMask();
    for (int pos = 0; pos < int(FloatLeaf::SIZE); ++pos) {
        const float value = src[pos];
        const bool isAbove = value > 0.0f;
        if (!active.isOn(openvdb::Index(pos))) {
            dst[pos] = isAbove ? FLT_BIG : -FLT_BIG;
            continue;
        }
        const int i = at(pos >> 6, (pos >> 3) & 7, pos & 7);
        // Slots 2 axis (negative side) and 2 axis + 1 (positive side).
        const float nbValue[6] = {pad[i - PS[0]], pad[i + PS[0]], pad[i - PS[1]],
                                  pad[i + PS[1]], pad[i - PS[2]], pad[i + PS[2]]};
        const bool less = value < 0.0f;
        bool crossing[6];
        bool any = false;
        for (int k = 0; k < 6; ++k) any |= crossing[k] = less != (nbValue[k] < 0.0f);
        if (!any) {
            dst[pos] = isAbove ? FLT_BIG : -FLT_BIG;
            mask.setOn(openvdb::Index(pos));
            ++sweeping;
            continue;
        }
        ++boundary;
        const float delta = value;
        if (!(delta > 1e-8f) && !(delta < -1e-8f)) {  // math::isApproxZero
            dst[pos] = 0.0f;
            continue;
        }
        float sum = 0.0f;
        for (int axis = 0; axis < 3; ++axis) {
            float d = FLT_BIG;
            if (crossing[2 * axis]) d = std::abs(delta / (value - nbValue[2 * axis]));
            if (crossing[2 * axis + 1]) {
                const float d2 = std::abs(delta / (value - nbValue[2 * axis + 1]));
                if (d2 < d) d = d2;
            }
            if (d < FLT_BIG) sum += 1.0f / (d * d);
        }
        dst[pos] = isAbove ? h / std::sqrt(sum) : -h / std::sqrt(sum);
    }
}

/// Step 2: the eight sweeps, in OpenVDB's order: +++, ---, ++-, --+, +-+, -+-, +--, -++ (bit a
/// of `dir` set: negative along axis a). Returns the leaf sweeps skipped.
///
/// A leaf is skipped in a sweep when sweeping it cannot change it. A voxel's update reads only
/// its own value and its six face neighbours, in any sweep direction; so when every voxel of a
/// leaf kept its value in a sweep (the leaf is "stable" on what it read), a later sweep that
/// reads the same values changes nothing either, whatever its direction. The leaf read its
/// upwind face-neighbour leaves after their sweep of that round, the downwind ones before
/// theirs (a leaf starts when its upwind neighbours are done, and its downwind ones wait for
/// it); each leaf records in which sweeps it changed, so that "has any neighbour changed between
/// what the leaf read when it was last stable and what it would read now" is a test of a few
/// bits. Skipping thus gives the values of the full sweeps, bit for bit.
std::size_t sweepAll(const LeafGraph& graph, const std::vector<LeafMask>& sweepMask, float h, float sqrt2h)
{
    const std::size_t leafCount = graph.leaves.size();
    static constexpr int DIRECTIONS[8] = {0, 7, 4, 3, 2, 5, 6, 1};
    std::vector<const float*> data(leafCount);
    for (std::size_t n = 0; n < leafCount; ++n) data[n] = graph.leaves[n]->buffer().data();
    std::vector<std::atomic<int>> pending(leafCount);
    std::vector<std::uint8_t> changedIn(leafCount, 0);  // bit r: changed in round r (sweep DIRECTIONS[r])
    std::vector<std::int8_t> lastStable(leafCount, -1);  // the last round the leaf was stable in, or -1
    std::vector<std::int32_t> ready;
    std::atomic<std::size_t> skipped{0};
    // Whether slot `s`'s neighbour is upwind in direction `dir` (swept before the leaf).
    auto isUpwind = [](int dir, int s) { return ((s & 1) != 0) == (((dir >> (s / 2)) & 1) != 0); };
    for (int round = 0; round < 8; ++round) {
        const int dir = DIRECTIONS[round];
        auto upwind = [&](int axis) { return slot(axis, ((dir >> axis) & 1) != 0); };
        auto downwind = [&](int axis) { return slot(axis, ((dir >> axis) & 1) == 0); };
        ready.clear();
        for (std::size_t n = 0; n < leafCount; ++n) {
            int count = 0;
            for (int axis = 0; axis < 3; ++axis) count += graph.neighbours[n][std::size_t(upwind(axis))] >= 0;
            pending[n].store(count, std::memory_order_relaxed);
            if (count == 0) ready.push_back(std::int32_t(n));
        }
        tbb::parallel_for_each(ready.begin(), ready.end(), [&](std::int32_t n, tbb::feeder<std::int32_t>& feeder) {
            const auto& nbIndex = graph.neighbours[std::size_t(n)];
            bool skip = false;
            if (const int stable = lastStable[std::size_t(n)]; stable >= 0) {
                skip = true;
                for (int s = 0; s < 6 && skip; ++s) {
                    const std::int32_t m = nbIndex[std::size_t(s)];
                    if (m < 0) continue;
                    // The rounds after which the neighbour's values were read then and now.
                    const int then = isUpwind(DIRECTIONS[stable], s) ? stable : stable - 1;
                    const int now = isUpwind(dir, s) ? round : round - 1;
                    const unsigned between = ((1u << (now + 1)) - 1u) & ~((1u << (then + 1)) - 1u);
                    if (changedIn[std::size_t(m)] & between) skip = false;
                }
            }
            if (skip) {
                skipped.fetch_add(1, std::memory_order_relaxed);
                lastStable[std::size_t(n)] = std::int8_t(round);
            } else {
                std::array<const float*, 6> nb{};
                for (int s = 0; s < 6; ++s)
                    nb[std::size_t(s)] =
                        nbIndex[std::size_t(s)] < 0 ? nullptr : data[std::size_t(nbIndex[std::size_t(s)])];
                if (sweepLeaf(graph.leaves[std::size_t(n)]->buffer().data(), nb, sweepMask[std::size_t(n)], dir, h,
                              sqrt2h)) {
                    changedIn[std::size_t(n)] = std::uint8_t(changedIn[std::size_t(n)] | (1u << round));
                    lastStable[std::size_t(n)] = -1;
                } else {
                    lastStable[std::size_t(n)] = std::int8_t(round);
                }
            }
            for (int axis = 0; axis < 3; ++axis) {
                const std::int32_t m = nbIndex[std::size_t(downwind(axis))];
                if (m >= 0 && pending[std::size_t(m)].fetch_sub(1, std::memory_order_acq_rel) == 1) feeder.add(m);
            }
        });
    }

    return skipped.load();
}

/// Step 3 (sweep(nIter, finalize = true)): the extrema of the active values that were reached;
/// unreached active voxels take them, and the inactive values and the background become the
/// outside (largest) and inside (smallest) value by their sign.
void finalise(const LeafGraph& graph, FloatTree& tree)
{
    const std::size_t leafCount = graph.leaves.size();
    using MinMax = std::pair<float, float>;
    const MinMax range = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, leafCount, 64), MinMax{FLT_BIG, -FLT_BIG},
        [&](const tbb::blocked_range<std::size_t>& r, MinMax m) {
            for (std::size_t n = r.begin(); n != r.end(); ++n)
                for (auto it = graph.leaves[n]->cbeginValueOn(); it; ++it) {
                    const float v = *it;
                    if (v != -FLT_BIG && v < m.first) m.first = v;
                    if (v != FLT_BIG && v > m.second) m.second = v;
                }
            return m;
        },
        [](const MinMax& a, const MinMax& b) { return MinMax{std::min(a.first, b.first), std::max(a.second, b.second)}; });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leafCount, 64), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t n = r.begin(); n != r.end(); ++n)
            for (auto it = graph.leaves[n]->beginValueOn(); it; ++it) {
                if (*it == -FLT_BIG) it.setValue(range.first);
                else if (*it == FLT_BIG) it.setValue(range.second);
            }
    });
    openvdb::tools::changeAsymmetricLevelSetBackground(tree, range.second, range.first);
}

} // namespace

openvdb::FloatGrid::Ptr redistance(openvdb::FloatGrid& f, std::size_t* skippedLeafSweeps)
{
    if (skippedLeafSweeps) *skippedLeafSweeps = 0;
    FloatTree& inTree = f.tree();
    if (inTree.hasActiveTiles())
        OPENVDB_THROW(openvdb::RuntimeError, "redistance: the input has active tiles (voxelize them first)");
    {
        // Exactly 0 reads as inside to the sign test below but as outside to the interface test
        // (see segment_tools.h): make it the smallest positive float.
        openvdb::tree::LeafManager<FloatTree> leaves(inTree);
        leaves.foreach([](FloatLeaf& leaf, std::size_t) {
            for (auto it = leaf.beginValueOn(); it; ++it)
                if (*it == 0.0f) it.setValue(std::numeric_limits<float>::min());
        });
    }
    openvdb::FloatGrid::Ptr out = f.deepCopy();
    FloatTree& tree = out->tree();
    const float h = static_cast<float>(out->voxelSize()[0]);
    const float sqrt2h = std::sqrt(2.0f) * h;

    LeafGraph graph(tree);
    const std::size_t leafCount = graph.leaves.size();
    std::vector<const FloatLeaf*> inLeaves(leafCount);
    for (std::size_t n = 0; n < leafCount; ++n) inLeaves[n] = inTree.probeConstLeaf(graph.leaves[n]->origin());

    // 1. Initialisation.
    std::vector<LeafMask> sweepMask(leafCount);
    std::atomic<std::uint64_t> sweepingVoxels{0}, boundaryVoxels{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leafCount, 16), [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const FloatTree> inAcc(inTree);
        std::uint64_t sweeping = 0, boundary = 0;
        for (std::size_t n = r.begin(); n != r.end(); ++n) {
            std::array<const float*, 6> nb{};
            for (int s = 0; s < 6; ++s) {
                const std::int32_t m = graph.neighbours[n][std::size_t(s)];
                nb[std::size_t(s)] = m < 0 ? nullptr : inLeaves[std::size_t(m)]->buffer().data();
            }
            initialiseLeaf(*inLeaves[n], nb, inAcc, h, graph.leaves[n]->buffer().data(), sweepMask[n], sweeping,
                           boundary);
        }
        sweepingVoxels += sweeping;
        boundaryVoxels += boundary;
    });
    // Tiles by their sign (there are no active ones), the background +FLT_MAX.
    {
        FloatTree::ValueAllIter it = tree.beginValueAll();
        it.setMaxDepth(FloatTree::ValueAllIter::LEAF_DEPTH - 1);  // the root's and internal nodes' values
        for (; it; ++it) it.setValue(*it > 0.0f ? FLT_BIG : -FLT_BIG);
    }
    tree.root().setBackground(FLT_BIG, /*updateChildNodes=*/false);
    // As sdfToSdf: with nothing to sweep or nothing to sweep from, the initialisation is returned.
    if (sweepingVoxels == 0 || boundaryVoxels == 0) return out;

    // 2. The sweeps; 3. finalisation.
    const std::size_t skipped = sweepAll(graph, sweepMask, h, sqrt2h);
    if (skippedLeafSweeps) *skippedLeafSweeps = skipped;
    finalise(graph, tree);
    return out;
}

} // namespace flyover::detail
