/// @file centerline_path.h
/// @brief The path geometry steps of the centerline (centerline.cpp, step 4): resampling, the
///        ridge of D and cross-section centring, twiced smoothing, the ends, the kinks.
#pragma once

#include "colon/centerline.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <vector>

namespace flyover::centerline_path {

/// The sdf (Sign 1) or D = -sdf (Sign -1) at a world position, sampled by `Sampler`. One probe
/// per thread (it owns a tree accessor).
template <typename Sampler, int Sign>
class GridProbe {
public:
    explicit GridProbe(const openvdb::FloatGrid& grid) : mAcc(grid.tree()), mXf(grid.transform()) {}
    double operator()(const Vec3d& worldMm)
    {
        float v = 0.0f;
        Sampler::sample(mAcc, mXf.worldToIndex(openvdb::Vec3d(worldMm.x, worldMm.y, worldMm.z)), v);
        if constexpr (Sign < 0) return -static_cast<double>(v);
        else return static_cast<double>(v);
    }

private:
    openvdb::tree::ValueAccessor<const openvdb::FloatTree> mAcc;
    const openvdb::math::Transform& mXf;
};

/// D = -sdf at a world position by triquadratic interpolation (27 voxels). Trilinear
/// interpolation of a distance field takes its extrema at voxel centres, which would snap a
/// ridge search back onto the voxel grid and bias D low on the axis; the quadratic stencil
/// follows the ridge between voxels.
using DepthProbe = GridProbe<openvdb::tools::QuadraticSampler, -1>;
/// The sdf by trilinear interpolation (mm).
using SdfProbe = GridProbe<openvdb::tools::BoxSampler, 1>;

Vec3d toVec(const openvdb::Vec3d& v);
/// Arc length at each vertex of a polyline.
std::vector<double> arcLengths(const std::vector<Vec3d>& pts);
/// Position at arc length `t` along the polyline (linear interpolation); `hint` is a vertex
/// index at or before `t` that the caller advances monotonically.
Vec3d pointAt(const std::vector<Vec3d>& pts, const std::vector<double>& s, double t, std::size_t& hint);
/// Resamples a polyline evenly in arc length, `spacing` apart (both ends included).
std::vector<Vec3d> resampleEven(const std::vector<Vec3d>& pts, double spacing);
/// Continues the path straight along its end tangent into the blind end until D falls to 60%
/// of its value at the end. Extends path.back().
void extendEnd(std::vector<Vec3d>& path, DepthProbe& depthAt, double fineMm);
/// From the voxel path of one piece to its smooth centerline, sampled every fineMm.
std::vector<Vec3d> refinePath(const std::vector<Vec3d>& raw, const openvdb::FloatGrid& grid, double voxelMm,
                              double fineMm, const CenterlineParams& params);
/// Smooths the path again where it still turns more than the kink bound per 1 mm (see the
/// definition for the rule); `fine` is evenly sampled every fineMm, and so is the result.
std::vector<Vec3d> removeKinks(const std::vector<Vec3d>& fine, const openvdb::FloatGrid& grid, double fineMm);
/// Outward unit tangents at the back and front ends: the chord over the last few millimetres.
Vec3d backOutward(const std::vector<Vec3d>& path, double voxelMm);
Vec3d frontOutward(const std::vector<Vec3d>& path, double voxelMm);

/// Stretches of the path closer to the wall than nearWallMm outside bridges.
std::vector<CenterlineNearWall> nearWallStretches(const Centerline& cl, const CenterlineParams& params);
/// The turns between consecutive steps and the normal's steps, into the report.
void reportTurns(const Centerline& cl, CenterlineReport& report);

} // namespace flyover::centerline_path
