#include "tests/shapes/test_shapes.h"
#include "volume/vec3.h"

#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

namespace flyover::test {

namespace {

openvdb::Vec3d toVdb(const Vec3d& v) { return {v.x, v.y, v.z}; }
Vec3d fromVdb(const openvdb::Vec3d& v) { return {v[0], v[1], v[2]}; }
Vec3d minOf(const Vec3d& a, const Vec3d& b)
{
    return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
Vec3d maxOf(const Vec3d& a, const Vec3d& b)
{
    return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}

/// For each leaf (8^3 voxels) of the local frame, the axis pieces within cutoffMm of it, so
/// that grid builders evaluate only nearby pieces.
class PieceBins {
public:
    PieceBins(const Axis& axis, double voxelMm, double cutoffMm)
    {
        for (std::size_t i = 0; i < axis.pieceCount(); ++i) {
            Vec3d lo, hi;
            axis.pieceBoundsMm(i, lo, hi);
            const Vec3d pad{cutoffMm, cutoffMm, cutoffMm};
            lo = (lo - pad) / voxelMm;
            hi = (hi + pad) / voxelMm;
            const openvdb::Coord a(int(std::floor(lo.x)) >> 3, int(std::floor(lo.y)) >> 3,
                                   int(std::floor(lo.z)) >> 3);
            const openvdb::Coord b(int(std::ceil(hi.x)) >> 3, int(std::ceil(hi.y)) >> 3,
                                   int(std::ceil(hi.z)) >> 3);
            for (int x = a.x(); x <= b.x(); ++x)
                for (int y = a.y(); y <= b.y(); ++y)
                    for (int z = a.z(); z <= b.z(); ++z)
                        mBins[openvdb::Coord(x << 3, y << 3, z << 3)].push_back(int(i));
        }
    }
    const std::vector<int>* near(const openvdb::Coord& leafOrigin) const
    {
        auto it = mBins.find(leafOrigin);
        return it == mBins.end() ? nullptr : &it->second;
    }
    const std::map<openvdb::Coord, std::vector<int>>& bins() const { return mBins; }

private:
    std::map<openvdb::Coord, std::vector<int>> mBins;
};

std::uint64_t splitMix64(std::uint64_t x)
{
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

/// Standard normal noise that depends only on (seed, voxel): reproducible with any threading.
double gaussianNoise(std::uint64_t seed, const openvdb::Coord& ijk)
{
    std::uint64_t h = splitMix64(seed);
    h = splitMix64(h ^ std::uint64_t(std::uint32_t(ijk.x())));
    h = splitMix64(h ^ std::uint64_t(std::uint32_t(ijk.y())));
    h = splitMix64(h ^ std::uint64_t(std::uint32_t(ijk.z())));
    const std::uint64_t h2 = splitMix64(h);
    const double u1 = (double(h >> 11) + 0.5) / 9007199254740992.0;  // (0, 1)
    const double u2 = double(h2 >> 11) / 9007199254740992.0;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * PI * u2);
}

double segmentDistance(const Vec3d& a, const Vec3d& b, const Vec3d& p, double& t)
{
    const Vec3d d = b - a;
    const double dd = dot(d, d);
    t = dd > 0 ? std::clamp(dot(p - a, d) / dd, 0.0, 1.0) : 0.0;
    return distance(p, a + d * t);
}

} // namespace

Vec3d Frame::worldFromLocal(const Vec3d& localMm) const
{
    return fromVdb(xf->indexToWorld(toVdb(localMm / voxelMm)));
}

Vec3d Frame::localFromWorld(const Vec3d& worldMm) const
{
    return fromVdb(xf->worldToIndex(toVdb(worldMm))) * voxelMm;
}

std::string Frame::describe() const
{
    std::ostringstream s;
    s << "frame{voxel " << voxelMm << " mm, index->world (row-vector) matrix "
      << xf->baseMap()->getAffineMap()->getMat4().str() << "}";
    return s.str();
}

Frame makeFrame(double voxelMm, bool rotated)
{
    Frame f;
    f.voxelMm = voxelMm;
    f.xf = openvdb::math::Transform::createLinearTransform(voxelMm);
    if (rotated) {
        f.xf->postRotate(0.5, openvdb::math::X_AXIS);
        f.xf->postRotate(-0.3, openvdb::math::Y_AXIS);
        f.xf->postRotate(0.8, openvdb::math::Z_AXIS);
        f.xf->postTranslate(openvdb::Vec3d(-123.4, 56.7, -890.1));
    }
    return f;
}

void Axis::add(Piece piece)
{
    piece.arc0 = mLength;
    mLength += piece.length;
    mPieces.push_back(piece);
}

Axis Axis::straight(const Vec3d& a, const Vec3d& b)
{
    Axis axis;
    Piece p;
    p.a = a;
    p.b = b;
    p.length = distance(a, b);
    axis.add(p);
    std::ostringstream s;
    s << "straight{(" << a.x << "," << a.y << "," << a.z << ") -> (" << b.x << "," << b.y << ","
      << b.z << ") mm}";
    axis.mDescription = s.str();
    return axis;
}

Axis Axis::helix(const Vec3d& center, double radiusMm, double riseMmPerRad, double turns,
                 double maxSegmentMm)
{
    Axis axis;
    const double tMax = 2.0 * PI * turns;
    const double total = tMax * std::sqrt(radiusMm * radiusMm + riseMmPerRad * riseMmPerRad);
    const int n = std::max(1, int(std::ceil(total / maxSegmentMm)));
    auto at = [&](double t) {
        return center + Vec3d{radiusMm * std::cos(t), radiusMm * std::sin(t), riseMmPerRad * t};
    };
    for (int i = 0; i < n; ++i) {
        Piece p;
        p.a = at(tMax * i / n);
        p.b = at(tMax * (i + 1) / n);
        p.length = distance(p.a, p.b);
        axis.add(p);
    }
    std::ostringstream s;
    s << "helix{center (" << center.x << "," << center.y << "," << center.z << "), radius "
      << radiusMm << " mm, rise " << riseMmPerRad << " mm/rad, turns " << turns << "}";
    axis.mDescription = s.str();
    return axis;
}

Axis Axis::uBend(const Vec3d& start, double leg1Mm, double leg2Mm, double bendRadiusMm)
{
    Axis axis;
    const double r = bendRadiusMm;
    Piece leg1;
    leg1.a = start;
    leg1.b = start + Vec3d{0, 0, leg1Mm};
    leg1.length = leg1Mm;
    axis.add(leg1);
    Piece arc;
    arc.isArc = true;
    arc.center = start + Vec3d{r, 0, leg1Mm};
    arc.u = {-1, 0, 0};
    arc.v = {0, 0, 1};
    arc.radius = r;
    arc.angle = PI;
    arc.length = PI * r;
    axis.add(arc);
    Piece leg2;
    leg2.a = start + Vec3d{2 * r, 0, leg1Mm};
    leg2.b = start + Vec3d{2 * r, 0, leg1Mm - leg2Mm};
    leg2.length = leg2Mm;
    axis.add(leg2);
    std::ostringstream s;
    s << "uBend{start (" << start.x << "," << start.y << "," << start.z << "), legs " << leg1Mm
      << " / " << leg2Mm << " mm, bend radius " << r << " mm}";
    axis.mDescription = s.str();
    return axis;
}

Vec3d Axis::start() const
{
    const Piece& p = mPieces.front();
    return p.isArc ? p.center + p.u * p.radius : p.a;
}

Vec3d Axis::end() const
{
    const Piece& p = mPieces.back();
    return p.isArc ? p.center + (p.u * std::cos(p.angle) + p.v * std::sin(p.angle)) * p.radius : p.b;
}

Vec3d Axis::tangentAtStart() const
{
    const Piece& p = mPieces.front();
    return p.isArc ? p.v : normalize(p.b - p.a);
}

Vec3d Axis::tangentAtEnd() const
{
    const Piece& p = mPieces.back();
    return p.isArc ? p.u * -std::sin(p.angle) + p.v * std::cos(p.angle) : normalize(p.b - p.a);
}

Axis::Closest Axis::closest(const Piece& piece, const Vec3d& p) const
{
    if (!piece.isArc) {
        double t;
        const double d = segmentDistance(piece.a, piece.b, p, t);
        return {d, piece.arc0 + t * piece.length};
    }
    const Vec3d q = p - piece.center;
    const double x = dot(q, piece.u), y = dot(q, piece.v);
    const Vec3d w = q - piece.u * x - piece.v * y;
    double phi = std::atan2(y, x);
    if (phi < 0) phi += 2 * PI;
    if (phi <= piece.angle) {
        const double rho = std::hypot(x, y);
        return {std::sqrt((rho - piece.radius) * (rho - piece.radius) + dot(w, w)),
                piece.arc0 + phi * piece.radius};
    }
    const Vec3d e0 = piece.center + piece.u * piece.radius;
    const Vec3d e1 =
        piece.center + (piece.u * std::cos(piece.angle) + piece.v * std::sin(piece.angle)) * piece.radius;
    const double d0 = distance(p, e0), d1 = distance(p, e1);
    return d0 <= d1 ? Closest{d0, piece.arc0} : Closest{d1, piece.arc0 + piece.length};
}

double Axis::distanceMm(const Vec3d& p) const
{
    double best = std::numeric_limits<double>::infinity();
    for (const Piece& piece : mPieces) best = std::min(best, closest(piece, p).distance);
    return best;
}

double Axis::distanceMm(const Vec3d& p, const std::vector<int>& ids) const
{
    double best = std::numeric_limits<double>::infinity();
    for (int i : ids) best = std::min(best, closest(mPieces[i], p).distance);
    return best;
}

Axis::Projection Axis::project(const Vec3d& p) const
{
    Projection best{std::numeric_limits<double>::infinity(), 0};
    for (const Piece& piece : mPieces) {
        const Closest c = closest(piece, p);
        if (c.distance < best.distanceMm) best = {c.distance, c.arcMm};
    }
    // Straight continuations beyond both ends.
    const Vec3d t0 = tangentAtStart(), t1 = tangentAtEnd();
    const double before = dot(start() - p, t0);
    if (before > 0) {
        const double d = distance(p, start() - t0 * before);
        if (d < best.distanceMm) best = {d, -before};
    }
    const double after = dot(p - end(), t1);
    if (after > 0) {
        const double d = distance(p, end() + t1 * after);
        if (d < best.distanceMm) best = {d, mLength + after};
    }
    return best;
}

void Axis::pieceBoundsMm(std::size_t i, Vec3d& lo, Vec3d& hi) const
{
    const Piece& p = mPieces[i];
    if (p.isArc) {
        const Vec3d r{p.radius, p.radius, p.radius};
        lo = p.center - r;
        hi = p.center + r;
    } else {
        lo = minOf(p.a, p.b);
        hi = maxOf(p.a, p.b);
    }
}

void Axis::boundsMm(Vec3d& lo, Vec3d& hi) const
{
    pieceBoundsMm(0, lo, hi);
    for (std::size_t i = 1; i < mPieces.size(); ++i) {
        Vec3d a, b;
        pieceBoundsMm(i, a, b);
        lo = minOf(lo, a);
        hi = maxOf(hi, b);
    }
}

openvdb::FloatGrid::Ptr makeTubeSdf(const Frame& frame, const Axis& axis, double radiusMm,
                                    int bandVoxels)
{
    const double h = frame.voxelMm;
    const float bandMm = float(bandVoxels * h);
    const PieceBins bins(axis, h, radiusMm + bandMm);
    auto tree = std::make_shared<openvdb::FloatTree>(bandMm);
    for (const auto& bin : bins.bins()) tree->touchLeaf(bin.first);
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(*tree);
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        const std::vector<int>* ids = bins.near(leaf.origin());
        for (auto it = leaf.beginValueAll(); it; ++it) {
            const openvdb::Coord ijk = it.getCoord();
            const Vec3d p = Vec3d{double(ijk.x()), double(ijk.y()), double(ijk.z())} * h;
            const double d = axis.distanceMm(p, *ids) - radiusMm;
            if (d <= bandMm) leaf.setValueOn(it.pos(), float(d));
            else leaf.setValueOff(it.pos(), bandMm);
        }
    });
    openvdb::tools::pruneInactive(*tree);
    auto grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(frame.xf->copy());
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    grid->setName("lumen_sdf");
    return grid;
}

double featureDistanceMm(const HuFeature& feature, const Vec3d& localMm)
{
    return feature.axis.distanceMm(localMm) - feature.radiusMm;
}

std::array<int64_t, 3> nearestVoxel(const ImageGeometry& g, const Vec3d& worldMm)
{
    const Vec3d ijk = g.indexFromWorld(worldMm);
    std::array<int64_t, 3> v{};
    for (int c = 0; c < 3; ++c)
        v[std::size_t(c)] = std::clamp<int64_t>(std::llround(ijk[c]), 0, g.size[std::size_t(c)] - 1);
    return v;
}

std::string HuPhantom::describe() const
{
    std::ostringstream s;
    s << "HuPhantom{" << frame.describe() << ", body index " << bodyIndex << ", tissue " << tissueHu
      << " HU, blur sigma " << blurSigmaMm << " mm, noise " << noiseHu << " HU, seed " << seed;
    for (const HuFeature& f : features)
        s << ", " << f.name << ": " << f.axis.describe() << " radius " << f.radiusMm << " mm at "
          << f.hu << " HU";
    s << "}";
    return s.str();
}

openvdb::FloatGrid::Ptr makeHuGrid(const HuPhantom& ph)
{
    const double h = ph.frame.voxelMm;
    const double reachMm = 5.0 * ph.blurSigmaMm + h;
    std::vector<PieceBins> bins;
    for (const HuFeature& f : ph.features) bins.emplace_back(f.axis, h, f.radiusMm + reachMm);

    auto tree = std::make_shared<openvdb::FloatTree>(-1000.0f);
    tree->sparseFill(ph.bodyIndex, float(ph.tissueHu), true);
    tree->voxelizeActiveTiles();
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(*tree);
    const double s = ph.blurSigmaMm * std::sqrt(2.0);
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        std::vector<const std::vector<int>*> near(ph.features.size());
        for (std::size_t f = 0; f < ph.features.size(); ++f) near[f] = bins[f].near(leaf.origin());
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const openvdb::Coord ijk = it.getCoord();
            const Vec3d p = Vec3d{double(ijk.x()), double(ijk.y()), double(ijk.z())} * h;
            double hu = ph.tissueHu;
            for (std::size_t f = 0; f < ph.features.size(); ++f) {
                if (!near[f]) continue;
                const HuFeature& feat = ph.features[f];
                const double d = feat.axis.distanceMm(p, *near[f]) - feat.radiusMm;
                // Fraction of the feature seen through a Gaussian point spread of a planar edge.
                const double a = 0.5 * std::erfc(d / s);
                hu += a * (feat.hu - hu);
            }
            it.setValue(float(hu + ph.noiseHu * gaussianNoise(ph.seed, ijk)));
        }
    });
    auto grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(ph.frame.xf->copy());
    grid->setName("ct");
    return grid;
}

} // namespace flyover::test
