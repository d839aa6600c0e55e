// Rectal tube: thin pieces left out by a morphological opening, measured along their
// geodesic axis, followed into the rectum by their ring, cut out (see rectal_tube.h).
#include "colon/rectal_tube.h"
#include "volume/vec3.h"

#include "volume/mask_components.h"
#include "volume/segment_tools.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <optional>

namespace flyover::detail {

namespace {

using openvdb::BoolTree;
using openvdb::Coord;
using BoolConstAccessor = openvdb::tree::ValueAccessor<const BoolTree>;
using FloatConstAccessor = openvdb::tree::ValueAccessor<const openvdb::FloatTree>;

/// Width of the geodesic distance bins whose centroids make the tube's axis (mm).
constexpr double AXIS_BIN_MM = 2.0;
/// Largest piece looked at (mL): a 10 mm tube 500 mm long.
constexpr double TUBE_MAX_VOLUME_ML = 40.0;
/// From a CT: the tube's wall (or the tissue around it) is not air: above this (HU). Not
/// higher: at 2.5 mm voxels partial volume leaves a 2 mm wall at -500..0 HU in most
/// directions (-200 found the ring in 5-9 of 12 directions on the small phantom, -500 in 10-12).
constexpr float RING_MIN_HU = -500.0f;
/// From a CT: inside the tube's lumen, air below this (HU).
constexpr float LUMEN_MAX_HU = -500.0f;
/// How far the tube is followed into the rectum at most (mm).
constexpr double MAX_FOLLOW_MM = 200.0;
/// Masks: the tube hangs from the wide part within this height above its lowest point (mm).
constexpr double LOWEST_END_REACH_MM = 60.0;
/// Directions around the axis sampled for the ring and for the body surface.
constexpr int RING_DIRECTIONS = 12;
/// The ring must show in at least this many of them; inside the rectum's air (the lumen all
/// round beyond the tube's wall), in at least RING_MIN_HITS_INSIDE.
constexpr int RING_MIN_HITS = 9;
constexpr int RING_MIN_HITS_INSIDE = 6;
/// Inside the rectum's air, the ring's directions without wall in a row: at most this many
/// (a side of the ring; not a half).
constexpr int RING_MAX_GAP_INSIDE = 4;
/// The tube is followed into the rectum along directions up to this far (degrees) from the
/// piece's last direction, in this many tilts and azimuths.
constexpr double FOLLOW_CONE_DEG = 90.0;
constexpr int FOLLOW_CONE_STEPS = 6;
constexpr int FOLLOW_CONE_AZIMUTHS = 8;
/// Straight runs at most (the tube bends where it enters the rectum, rarely more).
constexpr int FOLLOW_MAX_RUNS = 4;

const Coord FACE[6] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};

Vec3d toWorld(const openvdb::math::Transform& xf, const openvdb::Vec3d& ijk)
{
    const openvdb::Vec3d w = xf.indexToWorld(ijk);
    return {w[0], w[1], w[2]};
}

Coord nearestIndex(const openvdb::math::Transform& xf, const Vec3d& w)
{
    return Coord::round(xf.worldToIndex(openvdb::Vec3d(w.x, w.y, w.z)));
}

/// Two unit vectors completing `d` (unit) to an orthonormal frame.
void perpendiculars(const Vec3d& d, Vec3d& u, Vec3d& v)
{
    const Vec3d a = std::abs(d.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0};
    u = normalize(cross(d, a));
    v = cross(d, u);
}

double polylineLength(const std::vector<Vec3d>& p, std::size_t from, std::size_t to)
{
    double s = 0;
    for (std::size_t i = from; i + 1 <= to && i + 1 < p.size(); ++i) s += distance(p[i], p[i + 1]);
    return s;
}

/// One thin piece, measured along its geodesic axis from where it meets the wide part.
struct PieceAxis {
    std::vector<Vec3d> axis;   ///< bin centroids, from the attachment outwards
    Vec3d outerEnd;            ///< the voxel farthest (geodesically) from the attachment
    double lengthMm = 0;
    double diameterMm = 0;
    double strayMm = 0;        ///< largest distance of the axis from its chord
    bool touchesOutside = false;
    bool attached = false;
};

PieceAxis measurePiece(const BoolTree& piece, const BoolTree& wide, const openvdb::math::Transform& xf,
                       const TubeSearch& search)
{
    PieceAxis out;
    const double h = xf.voxelSize()[0];
    const double voxelMm3 = std::abs(xf.voxelVolume());
    openvdb::CoordBBox box;
    if (!piece.evalActiveVoxelBoundingBox(box)) return out;
    const Coord dim = box.dim();
    const std::int64_t nx = dim.x(), ny = dim.y(), nz = dim.z();
    if (nx * ny * nz > (std::int64_t(1) << 26)) return out;  // far too big for a tube's box
    auto at = [&](const Coord& c) {
        return std::size_t((c.x() - box.min().x()) + nx * ((c.y() - box.min().y()) + ny * (c.z() - box.min().z())));
    };
    // -2: not in the piece; -1: in it, not reached yet; >= 0: face steps from the attachment.
    std::vector<std::int32_t> steps(std::size_t(nx * ny * nz), -2);
    std::deque<Coord> queue;
    BoolConstAccessor wideAcc(wide);
    for (auto it = piece.cbeginValueOn(); it; ++it) {
        const Coord c = it.getCoord();
        bool attachment = false;
        for (const Coord& d : FACE) {
            const Coord n = c + d;
            if (wideAcc.isValueOn(n)) attachment = true;
            if (!out.touchesOutside && search.outside && search.outside(n)) out.touchesOutside = true;
        }
        steps[at(c)] = attachment ? 0 : -1;
        if (attachment) queue.push_back(c);
    }
    out.attached = !queue.empty();
    if (!out.attached) return out;
    std::int32_t farthest = 0;
    Coord farthestVoxel = queue.front();
    while (!queue.empty()) {
        const Coord c = queue.front();
        queue.pop_front();
        const std::int32_t s = steps[at(c)];
        if (s > farthest) {
            farthest = s;
            farthestVoxel = c;
        }
        for (const Coord& d : FACE) {
            const Coord n = c + d;
            if (!box.isInside(n)) continue;
            std::int32_t& t = steps[at(n)];
            if (t == -1) {
                t = s + 1;
                queue.push_back(n);
            }
        }
    }
    out.outerEnd = toWorld(xf, farthestVoxel.asVec3d());
    // The outside beyond the wall around the outer end (CT: a closed or connected outer end).
    const int reach = search.outsideReachVoxels;
    if (!out.touchesOutside && search.outside && reach > 0) {
        const openvdb::CoordBBox around(farthestVoxel - Coord(reach), farthestVoxel + Coord(reach));
        for (auto it = around.begin(); it && !out.touchesOutside; ++it)
            out.touchesOutside = search.outside(*it);
    }
    // Axis: centroids of the geodesic distance bins.
    const int bins = int(farthest * h / AXIS_BIN_MM) + 1;
    std::vector<openvdb::Vec3d> sum(std::size_t(bins), openvdb::Vec3d(0.0));
    std::vector<std::int64_t> count(std::size_t(bins), 0);
    for (auto it = piece.cbeginValueOn(); it; ++it) {
        const std::int32_t s = steps[at(it.getCoord())];
        if (s < 0) continue;  // not reached (cannot happen: the piece is connected)
        const std::size_t b = std::size_t(std::min(bins - 1, int(s * h / AXIS_BIN_MM)));
        sum[b] += it.getCoord().asVec3d();
        ++count[b];
    }
    std::vector<std::int64_t> axisCount;
    for (int b = 0; b < bins; ++b)
        if (count[std::size_t(b)] > 0) {
            out.axis.push_back(toWorld(xf, sum[std::size_t(b)] / double(count[std::size_t(b)])));
            axisCount.push_back(count[std::size_t(b)]);
        }
    if (out.axis.size() < 2) return out;
    out.lengthMm = polylineLength(out.axis, 0, out.axis.size() - 1);
    // Diameter of the middle part (the ends flare where the piece meets the wide part).
    std::size_t lo = out.axis.size() / 5, hi = out.axis.size() - 1 - out.axis.size() / 5;
    if (hi <= lo + 1) {
        lo = 0;
        hi = out.axis.size() - 1;
    }
    std::int64_t middle = 0;
    for (std::size_t i = lo; i <= hi; ++i) middle += axisCount[i];
    // Each bin centroid stands for half a bin on either side: the middle bins' voxels span
    // the polyline from lo to hi plus one bin spacing.
    const double spacing = out.lengthMm / double(out.axis.size() - 1);
    const double middleLength = polylineLength(out.axis, lo, hi) + spacing;
    if (middleLength > 0) out.diameterMm = 2.0 * std::sqrt(double(middle) * voxelMm3 / (PI * middleLength));
    for (const Vec3d& p : out.axis)
        out.strayMm = std::max(out.strayMm, distanceToSegment(p, out.axis.front(), out.axis.back()));
    return out;
}

/// World z of the lowest active voxel of `tree` (LPS: z is superior). Leaves whose corners
/// all lie above the lowest voxel found so far are skipped (z is affine in the index).
double lowestZ(const BoolTree& tree, const openvdb::math::Transform& xf)
{
    double z = std::numeric_limits<double>::max();
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        const openvdb::CoordBBox box = leaf->getNodeBoundingBox();
        double cornerLow = std::numeric_limits<double>::max();
        for (int c = 0; c < 8; ++c) {
            const Coord corner((c & 1) ? box.max().x() : box.min().x(), (c & 2) ? box.max().y() : box.min().y(),
                               (c & 4) ? box.max().z() : box.min().z());
            cornerLow = std::min(cornerLow, toWorld(xf, corner.asVec3d()).z);
        }
        if (cornerLow >= z) continue;
        for (auto it = leaf->cbeginValueOn(); it; ++it) z = std::min(z, toWorld(xf, it.getCoord().asVec3d()).z);
    }
    // Active tiles (none in practice: the sets are voxelised), by their origin as before.
    auto tiles = tree.cbeginValueOn();
    tiles.setMaxDepth(BoolTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tiles; ++tiles) z = std::min(z, toWorld(xf, tiles.getCoord().asVec3d()).z);
    return z;
}

} // namespace

int tubeWallReachVoxels(double voxelMm)
{
    return std::max(1, int(std::ceil((TUBE_MAX_WALL_MM + voxelMm) / voxelMm)));
}

bool nearInactive(const BoolTree& set, const openvdb::FloatTree& hu, int reach)
{
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    const int dim = int(FloatLeaf::DIM);
    FloatConstAccessor huAcc(hu);
    // Whether every voxel of `box` is active in `hu`, leaf by leaf (or tile by tile).
    auto allActive = [&](const openvdb::CoordBBox& box) {
        for (int x = box.min().x() & ~(dim - 1); x <= box.max().x(); x += dim)
            for (int y = box.min().y() & ~(dim - 1); y <= box.max().y(); y += dim)
                for (int z = box.min().z() & ~(dim - 1); z <= box.max().z(); z += dim) {
                    const Coord origin(x, y, z);
                    if (const FloatLeaf* leaf = huAcc.probeConstLeaf(origin)) {
                        if (!leaf->getValueMask().isOn()) return false;
                    } else if (!huAcc.isValueOn(origin)) {
                        return false;  // an inactive tile or the background
                    }
                }
        return true;
    };
    for (auto leaf = set.cbeginLeaf(); leaf; ++leaf) {
        if (leaf->isEmpty()) continue;
        openvdb::CoordBBox box = leaf->getNodeBoundingBox();
        box.expand(reach);
        if (allActive(box)) continue;
        for (auto it = leaf->cbeginValueOn(); it; ++it) {
            const openvdb::CoordBBox around(it.getCoord() - Coord(reach), it.getCoord() + Coord(reach));
            if (allActive(around)) continue;
            for (auto c = around.begin(); c; ++c)
                if (!huAcc.isValueOn(*c)) return true;
        }
    }
    return false;
}

namespace {

/// Step 1: the set split by an opening into its wide parts and the thin rest. A cube of half
/// side n voxels does not fit in a tube of radius TUBE_MAX_RADIUS_MM (its corners reach
/// n h sqrt 2); growing back m >= n sqrt 3 steps within the set covers every voxel of the wide
/// parts (the cube's corners reach n h sqrt 3). Null parts when either is empty.
struct WideAndThin {
    BoolTree::Ptr wide, thin;
};

WideAndThin splitWideAndThin(const BoolTree& set, double h)
{
    const int n = std::max(1, int(std::ceil(TUBE_MAX_RADIUS_MM / (h * std::sqrt(2.0)))));
    const int m = int(std::ceil(n * std::sqrt(3.0))) + 1;
    WideAndThin parts;
    parts.wide = std::make_shared<BoolTree>(set);
    BoolTree& wide = *parts.wide;
    erodeVoxels(wide, n, Neighbours::All);
    if (wide.empty()) return {};
    // Grown back one step at a time within the set; each step grows from the voxels the
    // previous one added (the rest of `wide` grew already): the same voxels as dilating the
    // whole of `wide` m times, at the cost of a shell.
    BoolTree::Ptr added = std::make_shared<BoolTree>(wide);
    for (int i = 0; i < m && !added->empty(); ++i) {
        dilateVoxels(*added, 1, Neighbours::All);
        added->topologyIntersection(set);
        added->topologyDifference(wide);
        pruneInactive(*added);
        wide.topologyUnion(*added);
    }
    parts.thin = std::make_shared<BoolTree>(set);
    BoolTree& thin = *parts.thin;
    thin.topologyDifference(wide);
    pruneInactive(thin);
    if (thin.empty()) return {};
    return parts;
}

/// Step 2: of the thin pieces, the longest that looks like a tube leaving the body (`pieces`
/// keeps it alive); null when none does.
const BoolTree* tubeLeavingBody(const std::vector<BoolTree::Ptr>& pieces, const BoolTree& set, const BoolTree& wide,
                                const openvdb::math::Transform& xf, const TubeSearch& search, PieceAxis& tube)
{
    const double h = xf.voxelSize()[0];
    const double voxelMl = std::abs(xf.voxelVolume()) / 1000.0;
    double wideLowZ = 0, setLowZ = 0;
    if (search.acceptLowestEnd) {
        wideLowZ = lowestZ(wide, xf);
        setLowZ = lowestZ(set, xf);
    }
    const BoolTree* tubePiece = nullptr;
    for (const BoolTree::Ptr& p : pieces) {
        const double ml = double(p->activeVoxelCount()) * voxelMl;
        if (ml > TUBE_MAX_VOLUME_ML) continue;
        if (ml < PI * 1.0 * TUBE_MIN_LENGTH_MM / 1000.0) break;  // sorted largest first: the rest are crumbs
        PieceAxis a = measurePiece(*p, wide, xf, search);
        if (!a.attached || a.axis.size() < 2) continue;
        if (a.lengthMm < TUBE_MIN_LENGTH_MM || a.diameterMm > TUBE_MAX_DIAMETER_MM) continue;
        if (a.strayMm > std::max(5.0, 0.2 * a.lengthMm)) continue;
        bool leaves = a.touchesOutside;
        if (search.acceptLowestEnd) {
            // A mask has no body: the piece must also hang from the lowest end of the wide
            // part (the rectum) downwards, to the image's edge or as the lowest point of all.
            leaves = (leaves || a.outerEnd.z <= setLowZ + h) && a.axis.front().z <= wideLowZ + LOWEST_END_REACH_MM &&
                     a.outerEnd.z < a.axis.front().z;
        }
        if (!leaves) continue;
        if (!tubePiece || a.lengthMm > tube.lengthMm) {
            tubePiece = p.get();
            tube = a;
        }
    }
    return tubePiece;
}

/// Step 3: the tube followed into the rectum while the cross-section shows it: the lumen
/// inside, and around it the wall (CT: dense; mask: not in the set).
class TubeFollower {
public:
    TubeFollower(const BoolTree& set, const openvdb::math::Transform& xf, const openvdb::FloatTree* hu, double radius)
        : mXf(xf), mH(xf.voxelSize()[0]), mRadius(radius), mSetAcc(set),
          mInsideProbe(radius + TUBE_MAX_WALL_MM + 2.0 * mH)
    {
        if (hu) mHuAcc.emplace(*hu);
    }

    /// A catheter may bend where it enters the rectum (the anal canal points elsewhere than the
    /// rectum's axis), so each straight run is looked for in a cone around the last direction:
    /// the direction that follows the tube farthest (the least tilted of equal ones). Runs
    /// follow from the end of the previous one; the followed polyline, from `start` along
    /// `heading`, resampled every AXIS_BIN_MM and centred on the core.
    std::vector<Vec3d> followFrom(const Vec3d& start, Vec3d heading);

    /// The centre of the tube's air core in the plane normal to d near p: the centroid of the
    /// lumen (interpolated: CT air, or the mask's inside) reached from p's nearest lumen sample
    /// within the core's radius and half a voxel, twice (a point off the axis by up to a voxel
    /// sees part of the core first). The straight runs and the bin centroids of the thin piece
    /// stray from the axis by up to a voxel; the core's centre is the axis.
    Vec3d centreOnCore(Vec3d p, const Vec3d& d);

private:
    /// A voxel's air: > 0 in the lumen (CT: LUMEN_MAX_HU - HU, outside the grid -1000; mask:
    /// +-0.5), so that interpolated it is > 0 nearer the lumen (airness below).
    double airAt(const Coord& c)
    {
        if (mHuAcc) {
            float hu = 0;
            return mHuAcc->probeValue(c, hu) ? double(LUMEN_MAX_HU - hu) : -1000.0;
        }
        return mSetAcc.isValueOn(c) ? 0.5 : -0.5;
    }
    bool inLumen(const Vec3d& p) { return airAt(nearestIndex(mXf, p)) > 0; }
    bool wallAt(const Vec3d& q)
    {
        const Coord c = nearestIndex(mXf, q);
        if (mHuAcc) {
            float hu = 0;
            return mHuAcc->probeValue(c, hu) && hu >= RING_MIN_HU;
        }
        return !mSetAcc.isValueOn(c);
    }
    /// airAt interpolated trilinearly at q (> 0: lumen).
    double airness(const Vec3d& q);
    /// The lumen all round p at the probe's distance (beyond the tube's wall): p lies inside
    /// the rectum's air, not against its wall nor in the anal canal.
    bool inColonAir(const Vec3d& p, const Vec3d& u, const Vec3d& v)
    {
        int hits = 0;
        for (int j = 0; j < RING_DIRECTIONS; ++j) {
            const double t = 2.0 * PI * j / RING_DIRECTIONS;
            hits += inLumen(p + (u * std::cos(t) + v * std::sin(t)) * mInsideProbe) ? 1 : 0;
        }
        return hits >= RING_MIN_HITS;
    }
    bool ringAround(const Vec3d& p, const Vec3d& u, const Vec3d& v);
    /// The last point of the straight run from `from` along `d` (misses of up to two steps
    /// allowed), at most `maxMm` long.
    Vec3d follow(const Vec3d& from, const Vec3d& d, double maxMm);

    const openvdb::math::Transform& mXf;
    const double mH, mRadius;
    BoolConstAccessor mSetAcc;
    std::optional<FloatConstAccessor> mHuAcc;
    const double mInsideProbe;
};

bool TubeFollower::ringAround(const Vec3d& p, const Vec3d& u, const Vec3d& v)
{
    int hits = 0, gap = 0, run = 0, leading = -1;
    for (int j = 0; j < RING_DIRECTIONS; ++j) {
        const double t = 2.0 * PI * j / RING_DIRECTIONS;
        const Vec3d e = u * std::cos(t) + v * std::sin(t);
        bool hit = false;
        for (double r = mRadius + 0.5 * mH; r <= mRadius + 3.0 && !hit; r += 0.5 * mH) hit = wallAt(p + e * r);
        if (hit) {
            ++hits;
            if (leading < 0) leading = run;
            run = 0;
        } else {
            gap = std::max(gap, ++run);
        }
    }
    gap = std::max(gap, run + std::max(leading, 0));  // the misses that wrap round
    // Inside the rectum's air no wall but the tube's lies this near its axis, so a ring with a
    // gap is still the tube: at coarse voxels a mask's 2 mm wall misses a whole side of the
    // ring over several slices, depending on where the axis lies in its voxels. Not a wall on
    // one side only (a point beside the tube, off its axis).
    return hits >= RING_MIN_HITS || (hits >= RING_MIN_HITS_INSIDE && gap <= RING_MAX_GAP_INSIDE && inColonAir(p, u, v));
}

double TubeFollower::airness(const Vec3d& q)
{
    const openvdb::Vec3d ijk = mXf.worldToIndex(openvdb::Vec3d(q.x, q.y, q.z));
    const Coord c0 = Coord::floor(ijk);
    const openvdb::Vec3d f = ijk - c0.asVec3d();
    double sum = 0;
    for (int k = 0; k < 8; ++k) {
        const Coord c = c0.offsetBy(k & 1, (k >> 1) & 1, (k >> 2) & 1);
        const double w =
            ((k & 1) ? f[0] : 1 - f[0]) * (((k >> 1) & 1) ? f[1] : 1 - f[1]) * (((k >> 2) & 1) ? f[2] : 1 - f[2]);
        sum += w * airAt(c);
    }
    return sum;
}

Vec3d TubeFollower::centreOnCore(Vec3d p, const Vec3d& d)
{
    Vec3d u, v;
    perpendiculars(d, u, v);
    const double step = 0.25 * mH, disc = mRadius + 0.5 * mH;
    const int n = int(std::ceil(disc / step));
    const int side = 2 * n + 1;
    for (int round = 0; round < 2; ++round) {
        std::vector<std::int8_t> state(std::size_t(side * side), 0);  // 0 unseen, 1 lumen, 2 reached
        int seed = -1;
        double seedDistance = std::numeric_limits<double>::max();
        for (int a = -n; a <= n; ++a)
            for (int b = -n; b <= n; ++b) {
                const double r = step * std::sqrt(double(a * a + b * b));
                if (r > disc) continue;
                if (airness(p + u * (a * step) + v * (b * step)) <= 0) continue;
                const int k = (a + n) + side * (b + n);
                state[std::size_t(k)] = 1;
                if (r < seedDistance) {
                    seedDistance = r;
                    seed = k;
                }
            }
        if (seed < 0) return p;
        std::vector<int> stack{seed};
        state[std::size_t(seed)] = 2;
        double su = 0, sv = 0;
        std::size_t count = 0;
        while (!stack.empty()) {
            const int k = stack.back();
            stack.pop_back();
            const int a = k % side - n, b = k / side - n;
            su += a * step;
            sv += b * step;
            ++count;
            const int next[4][2] = {{a - 1, b}, {a + 1, b}, {a, b - 1}, {a, b + 1}};
            for (const auto& q : next) {
                if (q[0] < -n || q[0] > n || q[1] < -n || q[1] > n) continue;
                const int m = (q[0] + n) + side * (q[1] + n);
                if (state[std::size_t(m)] != 1) continue;
                state[std::size_t(m)] = 2;
                stack.push_back(m);
            }
        }
        p = p + u * (su / double(count)) + v * (sv / double(count));
    }
    return p;
}

Vec3d TubeFollower::follow(const Vec3d& from, const Vec3d& d, double maxMm)
{
    Vec3d u, v;
    perpendiculars(d, u, v);
    Vec3d last = from;
    int misses = 0;
    for (double t = 0; t <= maxMm; t += 0.5 * mH) {
        const Vec3d p = from + d * t;
        if (inLumen(p) && ringAround(p, u, v)) {
            last = p;
            misses = 0;
        } else if (++misses > 2) {
            break;
        }
    }
    return last;
}

std::vector<Vec3d> TubeFollower::followFrom(const Vec3d& start, Vec3d heading)
{
    std::vector<Vec3d> followed{start};
    double followedMm = 0;
    for (int run = 0; run < FOLLOW_MAX_RUNS && followedMm < MAX_FOLLOW_MM; ++run) {
        // Each run starts from the core's centre: a start off the axis leaves the core early.
        const Vec3d from = followed.back() = centreOnCore(followed.back(), heading);
        const double maxMm = MAX_FOLLOW_MM - followedMm;
        Vec3d best = follow(from, heading, maxMm), bestDir = heading;
        Vec3d u, v;
        perpendiculars(heading, u, v);
        for (int tilt = 1; tilt <= FOLLOW_CONE_STEPS; ++tilt) {
            const double a = FOLLOW_CONE_DEG * PI / 180.0 * tilt / FOLLOW_CONE_STEPS;
            for (int k = 0; k < FOLLOW_CONE_AZIMUTHS; ++k) {
                const double b = 2.0 * PI * k / FOLLOW_CONE_AZIMUTHS;
                const Vec3d d = normalize(heading * std::cos(a) + (u * std::cos(b) + v * std::sin(b)) * std::sin(a));
                const Vec3d q = follow(from, d, maxMm);
                if (distance(from, q) > distance(from, best) + mH) {
                    best = q;
                    bestDir = d;
                }
            }
        }
        if (distance(from, best) < mH) break;  // no run of a voxel or more: the tip
        followedMm += distance(from, best);
        followed.push_back(best);
        heading = bestDir;
    }
    // Each run resampled every AXIS_BIN_MM, each sample moved to the core's centre (a run's
    // ends are centred, its straight line need not be).
    std::vector<Vec3d> centred{followed.front()};
    for (std::size_t i = 0; i + 1 < followed.size(); ++i) {
        const double len = distance(followed[i], followed[i + 1]);
        const Vec3d d = (followed[i + 1] - followed[i]) / len;
        const int samples = std::max(1, int(std::ceil(len / AXIS_BIN_MM)));
        for (int k = 1; k <= samples; ++k) centred.push_back(centreOnCore(followed[i] + d * (len * k / samples), d));
    }
    return centred;
}

/// Step 4: the tube's voxels: the thin piece, and the set's voxels within `reach` of the
/// followed stretch.
BoolTree::Ptr tubeVoxels(const BoolTree& tubePiece, const BoolTree& set, const openvdb::math::Transform& xf,
                         const std::vector<Vec3d>& followed, double reach)
{
    const double h = xf.voxelSize()[0];
    auto cut = std::make_shared<BoolTree>(tubePiece);
    BoolConstAccessor setAcc(set);
    for (std::size_t i = 0; i + 1 < followed.size(); ++i) {
        openvdb::CoordBBox box;
        for (const Vec3d& p : {followed[i], followed[i + 1]}) {
            const openvdb::Vec3d ijk = xf.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
            box.expand(Coord::floor(ijk));
            box.expand(Coord::floor(ijk) + Coord(1));
        }
        box.expand(int(std::ceil(reach / h)) + 1);
        openvdb::tree::ValueAccessor<BoolTree> cutAcc(*cut);
        for (auto it = box.begin(); it; ++it) {
            const Coord c = *it;
            if (!setAcc.isValueOn(c)) continue;
            if (distanceToSegment(toWorld(xf, c.asVec3d()), followed[i], followed[i + 1]) <= reach)
                cutAcc.setValueOn(c, true);
        }
    }
    return cut;
}

/// The body surface on a CT: going inwards from the outer end, the first axis point with the
/// body all around (active voxels beyond the wall); the outer end when there is none.
Vec3d bodyEntry(const PieceAxis& tube, const openvdb::FloatTree& hu, const openvdb::math::Transform& xf,
                const Vec3d& dir, double radius)
{
    FloatConstAccessor huAcc(hu);
    for (std::size_t i = tube.axis.size(); i-- > 0;) {
        const Vec3d p = tube.axis[i];
        const Vec3d d = normalize(tube.axis[i == 0 ? 0 : i - 1] - tube.axis[std::min(i + 1, tube.axis.size() - 1)]);
        Vec3d a, b;
        perpendiculars(length(d) > 0 ? d : dir, a, b);
        int inside = 0;
        for (int j = 0; j < RING_DIRECTIONS; ++j) {
            const double t = 2.0 * PI * j / RING_DIRECTIONS;
            const Coord c = nearestIndex(xf, p + (a * std::cos(t) + b * std::sin(t)) * (radius + 5.0));
            inside += huAcc.isValueOn(c) ? 1 : 0;
        }
        if (inside >= RING_DIRECTIONS - 2) return p;
    }
    return tube.outerEnd;
}

} // namespace

BoolTree::Ptr findRectalTube(const BoolTree& set, const openvdb::math::Transform& xf, const TubeSearch& search,
                             RectalTube& info, BoolTree::Ptr* fill)
{
    auto none = std::make_shared<BoolTree>(false);
    const double h = xf.voxelSize()[0];
    const double voxelMl = std::abs(xf.voxelVolume()) / 1000.0;
    // 1. Opening: the wide parts and the thin rest.
    const WideAndThin parts = splitWideAndThin(set, h);
    if (!parts.thin) return none;
    const BoolTree& wide = *parts.wide;

    // 2. The thin pieces that look like a tube leaving the body.
    const std::vector<BoolTree::Ptr> pieces = connectedComponents(*parts.thin);
    PieceAxis tube;
    const BoolTree* tubePiece = tubeLeavingBody(pieces, set, wide, xf, search, tube);
    if (!tubePiece) return none;

    // 3. Follow it into the rectum.
    const double radius = 0.5 * tube.diameterMm;
    const std::size_t back = std::min<std::size_t>(tube.axis.size() - 1, std::size_t(std::ceil(10.0 / AXIS_BIN_MM)));
    const Vec3d dir = normalize(tube.axis.front() - tube.axis[back]);
    TubeFollower follower(set, xf, search.hu, radius);
    std::vector<Vec3d> followed = follower.followFrom(follower.centreOnCore(tube.axis.front(), dir), dir);
    // Where the thin piece meets the rectum its bins may stray from the tube (thin air beside
    // it there: an air-fluid level, partial volume round the tube's wall), and a start there
    // may lie off the tube's core: the run found no tube and stopped a millimetre into the
    // rectum, 35 mm short of the tip (small phantom --rectal-tube seed 12 from the CT). So
    // the tube is also followed from the piece's bin `back` (10 mm before the attachment,
    // inside the anal canal, where tissue rings it); that run is taken, and the piece's bins
    // after `back` are left out of the axis, when it reaches more than two voxels farther
    // into the rectum (along `dir`, from the attachment).
    std::size_t pieceBins = tube.axis.size();
    if (back > 0 && search.hu) {
        std::vector<Vec3d> fromBack = follower.followFrom(follower.centreOnCore(tube.axis[back], dir), dir);
        auto reach = [&](const std::vector<Vec3d>& f) { return dot(f.back() - tube.axis.front(), dir); };
        if (reach(fromBack) > reach(followed) + 2.0 * h) {
            followed.swap(fromBack);
            pieceBins = tube.axis.size() - back;
        }
    }
    const double followedMm = polylineLength(followed, 0, followed.size() - 1);

    // 4. The tube's voxels: the thin piece, and the set's voxels within its lumen radius + a
    //    voxel of the followed stretch.
    BoolTree::Ptr cut = tubeVoxels(*tubePiece, set, xf, followed, radius + h);

    info = RectalTube{};
    info.found = true;
    info.tipMm = followed.back();
    info.outerEndMm = tube.outerEnd;
    info.diameterMm = tube.diameterMm;
    info.lengthMm = polylineLength(tube.axis, tube.axis.size() - pieceBins, tube.axis.size() - 1) + followedMm;
    info.volumeMl = double(cut->activeVoxelCount()) * voxelMl;
    info.axisMm.assign(tube.axis.rbegin(), tube.axis.rbegin() + std::ptrdiff_t(pieceBins));
    info.axisMm.insert(info.axisMm.end(), followed.begin() + 1, followed.end());
    info.entryMm = search.hu ? bodyEntry(tube, *search.hu, xf, dir, radius) : tube.outerEnd;

    // 5. The tube within the colon's air (rectalTubeFill).
    if (fill) {
        *fill = rectalTubeFill(set, *cut, xf, info);
        info.filledMl = double((*fill)->activeVoxelCount()) * voxelMl;
    }
    return cut;
}

BoolTree::Ptr rectalTubeFill(const BoolTree& lumen, const BoolTree& cut, const openvdb::math::Transform& xf,
                             const RectalTube& info)
{
    // Along the tube's axis, where the lumen lies all around beyond its wall, its lumen and
    // wall (the lumen radius + TUBE_MAX_WALL_MM + a voxel) are given to the lumen, so that the
    // surface and the path see the rectum as if the tube were not there (its rod would split
    // the rectum's medial axis around it).
    auto fill = std::make_shared<BoolTree>(false);
    if (!info.found || info.axisMm.size() < 2) return fill;
    const double h = xf.voxelSize()[0];
    const double radius = 0.5 * info.diameterMm;
    BoolConstAccessor setAcc(lumen);
    // The wall's outside, and a voxel of its partial volume (a CT's rim of not-quite-air).
    const double fillRadius = radius + TUBE_MAX_WALL_MM + h;
    const double probe = fillRadius + h;
    BoolConstAccessor cutRead(cut);
    auto lumenAt = [&](const Vec3d& q) {
        const Coord c = nearestIndex(xf, q);
        return setAcc.isValueOn(c) && !cutRead.isValueOn(c);
    };
    openvdb::tree::ValueAccessor<BoolTree> fillAcc(*fill);
    // The lumen all round q, a probe radius out in the plane of u and v.
    auto surrounded = [&](const Vec3d& q, const Vec3d& u, const Vec3d& v) {
        int hits = 0;
        for (int j = 0; j < RING_DIRECTIONS; ++j) {
            const double t = 2.0 * PI * j / RING_DIRECTIONS;
            hits += lumenAt(q + (u * std::cos(t) + v * std::sin(t)) * probe) ? 1 : 0;
        }
        return hits >= RING_MIN_HITS;
    };
    // A ball of fillRadius at q given to the lumen.
    auto fillBall = [&](const Vec3d& q) {
        const openvdb::Vec3d ijk = xf.worldToIndex(openvdb::Vec3d(q.x, q.y, q.z));
        openvdb::CoordBBox box(Coord::floor(ijk), Coord::floor(ijk) + Coord(1));
        box.expand(int(std::ceil(fillRadius / h)) + 1);
        for (auto it = box.begin(); it; ++it)
            if (distance(toWorld(xf, (*it).asVec3d()), q) <= fillRadius) fillAcc.setValueOn(*it, true);
    };
    const std::vector<Vec3d>& ax = info.axisMm;
    for (std::size_t i = 0; i + 1 < ax.size(); ++i) {
        const double len = distance(ax[i], ax[i + 1]);
        if (len <= 0) continue;
        const Vec3d d = (ax[i + 1] - ax[i]) / len;
        Vec3d u, v;
        perpendiculars(d, u, v);
        const int samples = std::max(1, int(std::ceil(len / (0.5 * h))));
        bool previous = surrounded(ax[i], u, v);
        Vec3d pu, pv;
        const Vec3d pd = i > 0 ? normalize(ax[i] - ax[i - 1]) : d;
        perpendiculars(pd, pu, pv);
        if (previous && i > 0 && surrounded(ax[i] - pd * fillRadius, pu, pv) &&
            surrounded(ax[i] + d * fillRadius, u, v)) {
            // The joint with the previous stretch, well inside: a ball (no wedge left out
            // on the outside of a bend).
            fillBall(ax[i]);
        }
        for (int k = 0; k < samples; ++k) {
            const Vec3d q0 = ax[i] + d * (len * k / samples);
            const Vec3d q1 = ax[i] + d * (len * (k + 1) / samples);
            const bool next = surrounded(q1, u, v);
            const bool both = previous && next;
            previous = next;
            if (!both) continue;
            // The voxels within fillRadius of [q0, q1] that project onto it.
            openvdb::CoordBBox box;
            for (const Vec3d& p : {q0, q1}) {
                const openvdb::Vec3d ijk = xf.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
                box.expand(Coord::floor(ijk));
                box.expand(Coord::floor(ijk) + Coord(1));
            }
            box.expand(int(std::ceil(fillRadius / h)) + 1);
            const double piece = distance(q0, q1);
            for (auto it = box.begin(); it; ++it) {
                const Vec3d w = toWorld(xf, (*it).asVec3d());
                const double t = dot(w - q0, d);
                if (t < 0 || t > piece) continue;
                if (distance(w, q0 + d * t) <= fillRadius) fillAcc.setValueOn(*it, true);
            }
        }
    }
    // The tube's closed tip: its cap of wall lies beyond the last axis point. Where the
    // lumen surrounds the tip, a ball of fillRadius there gives the cap to the lumen.
    if (ax.size() >= 2) {
        const Vec3d& q = ax.back();
        const Vec3d d = normalize(ax.back() - ax[ax.size() - 2]);
        Vec3d u, v;
        perpendiculars(d, u, v);
        if (surrounded(q, u, v) && lumenAt(q + d * probe)) fillBall(q);
    }
    // The tube's own voxels (`cut`) where the lumen lies all round them, with the tube's wall
    // (a ball of the wall and a voxel). The axis may stray from the tube where its thin piece
    // meets the rectum: at the anal verge, with tagged fluid up to the tube, the thin piece
    // holds other thin air by the air-fluid level, its axis bins there strayed up to 7 mm,
    // and the balls along them left specks of the tube's wall in the lumen (the path kept
    // 10 mm off the rectum's axis). "All round": of the 26 neighbour directions at the probe's
    // distance, those that do not meet the tube and its wall (along the tube), at least half,
    // lie in the lumen in the proportion RING_MIN_HITS / RING_DIRECTIONS; in the anal canal
    // they meet its tissue.
    const double wallRadius = TUBE_MAX_WALL_MM + h;
    const int reach = int(std::ceil(wallRadius / h));
    // A ball of wallRadius round a voxel.
    std::vector<Coord> ball;
    for (int dz = -reach; dz <= reach; ++dz)
        for (int dy = -reach; dy <= reach; ++dy)
            for (int dx = -reach; dx <= reach; ++dx)
                if (h * std::sqrt(double(dx * dx + dy * dy + dz * dz)) <= wallRadius) ball.emplace_back(dx, dy, dz);
    BoolTree tubeZone(false);  // the tube and its wall
    {
        openvdb::tree::ValueAccessor<BoolTree> zoneAcc(tubeZone);
        for (auto it = cut.cbeginValueOn(); it; ++it)
            for (const Coord& o : ball) zoneAcc.setValueOn(it.getCoord() + o, true);
    }
    BoolConstAccessor zoneRead(tubeZone);
    std::vector<Vec3d> probes;  // the 26 neighbour directions, the probe's distance long
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
                if (dx != 0 || dy != 0 || dz != 0) probes.push_back(normalize(Vec3d{double(dx), double(dy), double(dz)}) * probe);
    for (auto it = cut.cbeginValueOn(); it; ++it) {
        const Coord c = it.getCoord();
        const Vec3d w = toWorld(xf, c.asVec3d());
        int hits = 0, seen = 0;
        for (const Vec3d& e : probes) {
            const Coord q = nearestIndex(xf, w + e);
            if (zoneRead.isValueOn(q)) continue;
            ++seen;
            hits += setAcc.isValueOn(q) ? 1 : 0;
        }
        if (2 * seen < int(probes.size()) || hits * RING_DIRECTIONS < RING_MIN_HITS * seen) continue;
        for (const Coord& o : ball) fillAcc.setValueOn(c + o, true);
    }
    return fill;
}

} // namespace flyover::detail
