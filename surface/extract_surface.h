/// @file extract_surface.h
/// @brief Lumen level set -> inward-oriented triangle mesh (OpenVDB volumeToMesh, quads
///        split into triangles, into OpenMesh), with the checks that make OST trustworthy.
#pragma once

#include "surface/mesh_types.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <cstdint>

namespace flyover {

struct MeshParams {
    double isoValueMm = 0.0;   ///< iso-value of the level set to extract (mm)
    double adaptivity = 0.0;   ///< volumeToMesh adaptivity, 0..1 (0 = uniform)
    static constexpr int VERSION = 1;
};

/// Measures of a mesh, recorded in the manifest.
struct MeshStats {
    int64_t vertices = 0;
    int64_t faces = 0;
    int64_t components = 0;         ///< edge-connected face components
    int64_t boundaryEdges = 0;      ///< 0 for a closed surface
    int64_t droppedFaces = 0;       ///< faces OpenMesh refused (would be non-manifold)
    int64_t degenerateFaces = 0;    ///< zero-area faces kept in the mesh (no normal, never hit)
    double areaMm2 = 0;
    double enclosedVolumeMm3 = 0;   ///< signed volume; POSITIVE for an inward-oriented closed lumen
    double inwardFraction = 0;      ///< fraction of non-degenerate faces whose normal points to
                                    ///< decreasing SDF
};

/// @param sdf  signed distance grid (world mm), negative inside the lumen
/// @throw InputError when the level set has no zero crossing
TriMesh extractSurface(const openvdb::FloatGrid& sdf, const MeshParams& params,
                       MeshStats* stats = nullptr, Progress* progress = nullptr);

/// Fraction of faces whose normal agrees with -grad(sdf) at the face centroid (points into
/// the region where the SDF is negative). Zero-area faces have no normal and are left out of
/// the count; faces where the gradient vanishes (outside the narrow band) count as not inward.
/// @return 0 for a mesh without non-degenerate faces
double inwardFaceFraction(const TriMesh& mesh, const openvdb::FloatGrid& sdf);

/// Signed enclosed volume (mm^3) by the divergence theorem with the face normals as given.
/// For a closed surface whose normals point inward it is NEGATIVE of the usual outward
/// convention; we return -sum(...) so that an inward-oriented closed lumen gives a
/// positive volume.
double enclosedVolumeInward(const TriMesh& mesh);

double surfaceAreaMm2(const TriMesh& mesh);

} // namespace flyover
