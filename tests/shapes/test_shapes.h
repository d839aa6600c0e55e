/// @file test_shapes.h
/// @brief Analytic test shapes (style.md §12) for the volume tests: tube axes with closed-form
///        distance (straight capsule, helix, U-bend; a sphere is a zero-length capsule), built
///        either as a signed distance grid or as a noisy HU grid with partial-volume edges.
///
/// Shapes are defined in a *local* frame in mm whose axes are the grid's index axes scaled
/// by the voxel size (local = index * voxelMm). The grid transform maps index to world (LPS mm)
/// and may add a rotation and a translation, so that code under test that forgets to go
/// through grid.transform() fails. Tests compare in local mm via Frame::localFromWorld.
#pragma once

#include "volume/image.h"
#include "volume/progress.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <iostream>
#include <string>
#include <vector>

namespace flyover::test {

/// index -> world transform of a test grid, plus the local (index * voxelMm) frame.
struct Frame {
    double voxelMm = 1.0;
    openvdb::math::Transform::Ptr xf;  ///< index -> world (LPS mm)

    Vec3d worldFromLocal(const Vec3d& localMm) const;
    Vec3d localFromWorld(const Vec3d& worldMm) const;
    std::string describe() const;
};

/// @param rotated  add a rotation about an oblique axis and a translation to the transform
Frame makeFrame(double voxelMm, bool rotated);

/// A tube axis made of straight segments and circular arcs, in local mm.
class Axis {
public:
    static Axis straight(const Vec3d& a, const Vec3d& b);
    static Axis sphere(const Vec3d& center) { return straight(center, center); }
    /// Helix around the local z axis through `center`: center + (R cos t, R sin t, rise * t),
    /// t in [0, 2 pi turns], as a polyline of segments no longer than maxSegmentMm.
    static Axis helix(const Vec3d& center, double radiusMm, double riseMmPerRad, double turns,
                      double maxSegmentMm = 0.25);
    /// Leg 1 from `start` along +z (leg1Mm), a half circle of bendRadiusMm in the x-z plane
    /// towards +x, leg 2 back down along -z (leg2Mm).
    static Axis uBend(const Vec3d& start, double leg1Mm, double leg2Mm, double bendRadiusMm);

    double lengthMm() const { return mLength; }
    Vec3d start() const;
    Vec3d end() const;
    /// Distance to the axis itself (so a tube of radius r has hemispherical end caps).
    double distanceMm(const Vec3d& p) const;
    /// Distance restricted to the pieces listed in `ids` (see PieceBins).
    double distanceMm(const Vec3d& p, const std::vector<int>& ids) const;

    struct Projection {
        double distanceMm;  ///< to the axis continued straight beyond both ends
        double arcMm;       ///< arc length of the closest point (< 0 or > length on the extensions)
    };
    Projection project(const Vec3d& p) const;

    void boundsMm(Vec3d& lo, Vec3d& hi) const;
    std::size_t pieceCount() const { return mPieces.size(); }
    void pieceBoundsMm(std::size_t i, Vec3d& lo, Vec3d& hi) const;
    const std::string& describe() const { return mDescription; }

private:
    struct Piece {
        bool isArc = false;
        Vec3d a, b;              // segment ends
        Vec3d center, u, v;      // arc: center + R (cos t u + sin t v), t in [0, angle]
        double radius = 0, angle = 0;
        double arc0 = 0;         // arc length at the piece start
        double length = 0;
    };
    struct Closest {
        double distance;
        double arcMm;
    };
    Closest closest(const Piece& piece, const Vec3d& p) const;
    Vec3d tangentAtStart() const;
    Vec3d tangentAtEnd() const;
    void add(Piece piece);

    std::vector<Piece> mPieces;
    double mLength = 0;
    std::string mDescription;
};

/// Signed distance grid (world mm, negative inside) of a tube of radiusMm around `axis`:
/// active on the whole interior and an exterior band of bandVoxels; level-set class,
/// background +bandVoxels * voxelMm, name "lumen_sdf".
openvdb::FloatGrid::Ptr makeTubeSdf(const Frame& frame, const Axis& axis, double radiusMm,
                                    int bandVoxels = 3);

/// One structure of a HU phantom: a tube of radiusMm around `axis` filled with `hu`.
struct HuFeature {
    std::string name;
    Axis axis;
    double radiusMm = 0;
    double hu = -1000;
};

/// A body box of soft tissue (active voxels) with features; outside the box: inactive
/// background -1000. Edges are blurred by a Gaussian point spread (erf profile, so the
/// boundary sits at the HU midpoint) and voxels get seeded Gaussian noise.
struct HuPhantom {
    Frame frame;
    openvdb::CoordBBox bodyIndex;
    double tissueHu = 40;
    double blurSigmaMm = 0.6;
    double noiseHu = 15;
    std::uint64_t seed = 1;
    std::vector<HuFeature> features;  ///< painted in order, later ones over earlier ones

    std::string describe() const;
};

openvdb::FloatGrid::Ptr makeHuGrid(const HuPhantom& phantom);

/// Signed distance (mm) from `localMm` to the feature's tube surface (negative inside).
double featureDistanceMm(const HuFeature& feature, const Vec3d& localMm);

/// Index of the voxel whose centre is nearest to a world point (clamped to the image).
std::array<int64_t, 3> nearestVoxel(const ImageGeometry& g, const Vec3d& worldMm);

/// Prints the wall time spent in each reported step (for the timing tests).
struct TimingProgress : Progress {
    std::chrono::steady_clock::time_point last = std::chrono::steady_clock::now();
    std::string step = "start";
    void update(double, const std::string& what) override
    {
        const auto now = std::chrono::steady_clock::now();
        std::cout << "    " << step << ": " << std::chrono::duration<double>(now - last).count()
                  << " s\n";
        last = now;
        step = what;
    }
};

} // namespace flyover::test
