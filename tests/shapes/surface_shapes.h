/// @file surface_shapes.h
/// @brief Analytic shapes for the surface tests (style.md §12): signed distance grids sampled
///        from closed-form distances (exact at voxel centres), their "staircase" versions
///        (a binary voxel mask as a level set: +-half a voxel), and a ray caster for heights.
#pragma once

#include "surface/mesh_types.h"
#include "volume/vec3.h"

#include <openvdb/openvdb.h>

#include <functional>
#include <string>

namespace flyover::test {

using DistanceFn = std::function<double(const openvdb::Vec3d& pMm)>;

/// Samples `distanceMm` (world mm, negative inside) at the voxel centres of [loMm, hiMm] into
/// a narrow-band level set of halfWidthVoxels, then flood-fills the sign of the inactive
/// interior. Voxels outside [lo, hi] stay inactive (a shape cut by them is left open there).
openvdb::FloatGrid::Ptr sampleSdf(const DistanceFn& distanceMm, const openvdb::Vec3d& loMm,
                                  const openvdb::Vec3d& hiMm, double voxelMm, double halfWidthVoxels = 3.0);

/// The voxel-mask version of the same shape: -h/2 at voxel centres inside, +h/2 outside, so
/// the zero crossing lies halfway between inside and outside voxel centres: the staircase a
/// binary segmentation gives.
openvdb::FloatGrid::Ptr sampleStaircaseSdf(const DistanceFn& distanceMm, const openvdb::Vec3d& loMm,
                                           const openvdb::Vec3d& hiMm, double voxelMm);

/// Distance along the unit direction `dirMm` from `originMm` to the first face of `mesh` hit
/// on either side (brute force over all faces); tMaxMm when nothing is hit before it.
double firstHitMm(const TriMesh& mesh, const OpenMesh::Vec3d& originMm, const OpenMesh::Vec3d& dir,
                  double tMaxMm);

/// Mean and largest angle (degrees) between each face's normal and a reference direction
/// at its centroid (e.g. the analytic surface normal pointing into the lumen).
struct AngleError {
    double meanDeg = 0;
    double maxDeg = 0;
};
AngleError normalAngleError(const TriMesh& mesh,
                            const std::function<OpenMesh::Vec3d(const OpenMesh::Vec3d& pMm)>& inwardNormal);

/// A polyp as the phantom builds it: a ball of radius radiusMm centred at centreMm on the
/// fold-free wall of a tube, outwardDir the unit direction from the tube's axis point
/// axisMm to the centre (so centre = axis + outwardDir * tubeRadiusMm), tangent the axis
/// direction there.
struct PolypSite {
    OpenMesh::Vec3d axisMm, tangent, outwardDir, centreMm;
    double radiusMm = 0, tubeRadiusMm = 0;
};

/// Height (mm) of a polyp on a mesh: wall level minus apex level, both measured along
/// outwardDir from the axis point. Apex level: |centre - axis| minus the distance from the
/// centre along -outwardDir to the first mesh crossing (the tip, seen from inside the polyp,
/// so nothing in the lumen can hide it). Wall level: the farthest first hit from the axis
/// point along outwardDir turned about the tangent by +-theta and +-1.5 theta, where theta
/// puts the wall point 2 mm beyond the polyp's rim (folds can only shorten a hit, so the
/// farthest is the wall). The truth is radiusMm, whatever the mesh's overall offset.
double polypHeightMm(const TriMesh& mesh, const PolypSite& polyp);

/// A copy of `mesh` with every face's winding reversed.
TriMesh flipped(const TriMesh& mesh);

} // namespace flyover::test
