/// @file extract_surface.h
/// @brief Lumen level set -> inward-oriented triangle mesh (OpenVDB volumeToMesh, quads
///        split into triangles, into OpenMesh), with the checks that make OST trustworthy.
#pragma once

#include "surface/mesh_types.h"
#include "volume/progress.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace flyover {

/// Parameters of the mesh stage: extraction, smoothing, decimation (see lumen_surface.h for
/// the order). Defaults and the measurements behind them: docs in lumen_surface.h.
struct MeshParams {
    double isoValueMm = 0.0;   ///< iso-value of the level set to extract (mm)
    double adaptivity = 0.0;   ///< volumeToMesh adaptivity, 0..1 (0 = uniform)
    std::string smoothMethod = "taubin";  ///< "taubin" (lambda|mu, non-shrinking) or "none"
    int smoothIterations = 40;            ///< Taubin lambda|mu pairs (>= 0)
    double smoothPassBand = 0.05;         ///< Taubin pass band k_PB, in (0, 1)
    int decimateTargetFaces = 0;          ///< triangle budget (0 = none)
    double decimateFraction = 1.0;        ///< keep this fraction of the faces, (0, 1] (1 = none)
    double decimateMaxErrorVoxels = 0.0;  ///< bound on vertex-to-surface error (voxels; 0 = none)
    double decimateMaxNormalDeviationDeg = 45.0;  ///< normal-flip guard per collapse (degrees)
    static constexpr int VERSION = 2;
};

/// Measures of the mesh extractSurface returns (before smoothing and decimation).
struct MeshStats {
    int64_t vertices = 0;
    int64_t faces = 0;
    int64_t components = 0;         ///< edge-connected face components
    int64_t boundaryEdges = 0;      ///< 0 for a closed surface
    int64_t droppedFaces = 0;       ///< faces OpenMesh refused (would be non-manifold)
    /// Degenerate faces (isDegenerateTriangle) volumeToMesh emits where corners coincide are
    /// repaired by edge collapses (a needle) or flips (a cap): the operations, and the faces
    /// the collapses removed. faces + droppedFaces + removedDegenerateFaces = triangles in.
    int64_t degenerateRepairs = 0;
    int64_t removedDegenerateFaces = 0;
    int64_t degenerateFaces = 0;    ///< degenerate faces left after the repair (never hit by a
                                    ///< ray, no orientation)
    /// In volumeToMesh's triangles (quads split), before OpenMesh sees them: edges shared by
    /// more than two triangles, and edges two triangles traverse in the same direction
    /// (an orientation conflict between neighbours).
    int64_t nonManifoldEdges = 0;
    int64_t orientationConflicts = 0;
    double areaMm2 = 0;
    double enclosedVolumeMm3 = 0;   ///< signed volume; POSITIVE for an inward-oriented closed lumen
    double inwardFraction = 0;      ///< fraction of non-degenerate faces whose normal points to
                                    ///< decreasing SDF
};

/// One face's class against a level set (see FaceOrientation).
enum class FaceSide { Inward, Outward, Degenerate, NoGradient };

/// Per-face orientation against a level set, counted by checkFaceOrientation.
struct FaceOrientation {
    int64_t inward = 0;      ///< normal . -grad(sdf) > 0 at the centroid: into the lumen
    int64_t outward = 0;     ///< normal . -grad(sdf) <= 0
    int64_t degenerate = 0;  ///< no usable normal (isDegenerateTriangle)
    int64_t noGradient = 0;  ///< zero gradient (outside the narrow band): orientation unknown

    int64_t& of(FaceSide side)
    {
        switch (side) {
        case FaceSide::Outward: return outward;
        case FaceSide::Degenerate: return degenerate;
        case FaceSide::NoGradient: return noGradient;
        case FaceSide::Inward: break;
        }
        return inward;
    }
    void add(FaceSide side) { ++of(side); }

    /// inward / (faces - degenerate); 0 without oriented faces.
    double inwardFraction() const
    {
        const int64_t oriented = inward + outward + noGradient;
        return oriented > 0 ? double(inward) / double(oriented) : 0.0;
    }
};

/// volumeToMesh's triangles (quads split, wound as the mesh's faces), vertex indices into its
/// points, before OpenMesh sees them.
using TriangleSoup = std::vector<std::array<uint32_t, 3>>;

/// In `soup`: the edges shared by more than two triangles and the edges two triangles traverse
/// in the same direction (MeshStats::nonManifoldEdges, orientationConflicts).
std::pair<int64_t, int64_t> countSoupEdgeProblems(const TriangleSoup& soup);

/// @param sdf  signed distance grid (world mm), negative inside the lumen
/// @param surfaceStats  false: `stats` gets the counts only (vertices, faces, boundary edges,
///        dropped faces, degenerate repairs, non-manifold edges, orientation conflicts) and
///        leaves components, area, enclosed volume, degenerate faces and inward fraction 0:
///        those cost a pass over every face and the level set (the mesh stage's report does not
///        show them; its checks measure the final mesh)
/// @param soup  if given, receives the triangle soup, and `stats` leaves nonManifoldEdges and
///        orientationConflicts 0 for the caller to count later (countSoupEdgeProblems): a
///        sort of three keys per triangle that the mesh itself does not need
/// @throw InputError when the level set has no zero crossing
TriMesh extractSurface(const openvdb::FloatGrid& sdf, const MeshParams& params,
                       MeshStats* stats = nullptr, Progress* progress = nullptr, bool surfaceStats = true,
                       std::shared_ptr<const TriangleSoup>* soup = nullptr);

/// Classifies every face of `mesh` by whether its normal agrees with -grad(sdf) at its
/// centroid (central differences over one voxel, trilinear samples in world space).
/// @param notInward  if given, receives the faces that are not inward (any other class)
/// @param notInwardSides  if given, receives the class of each of those faces
FaceOrientation checkFaceOrientation(const TriMesh& mesh, const openvdb::FloatGrid& sdf,
                                     std::vector<TriMesh::FaceHandle>* notInward = nullptr,
                                     std::vector<FaceSide>* notInwardSides = nullptr);

/// The same test for one triangle at a time (for guards inside smoothing and decimation).
/// Keeps a grid accessor: use one instance per thread. The grid must outlive it.
class LumenSideTest {
public:
    explicit LumenSideTest(const openvdb::FloatGrid& sdf);
    ~LumenSideTest();
    LumenSideTest(const LumenSideTest&) = delete;
    LumenSideTest& operator=(const LumenSideTest&) = delete;

    /// True when the triangle's normal (b - a) x (c - a) points to decreasing SDF at its
    /// centroid; false for an outward, degenerate or gradient-free triangle.
    bool isInward(const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b, const OpenMesh::Vec3d& c) const;

    /// The triangle's class (as checkFaceOrientation counts it); `gradient`, if given, receives
    /// the central-difference gradient it used (unchanged for a degenerate triangle).
    FaceSide classify(const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b, const OpenMesh::Vec3d& c,
                      OpenMesh::Vec3d* gradient = nullptr) const;

    /// The level set at a world point (mm) as the test reads it: trilinear, exactly the value
    /// of OpenVDB's GridSampler<ConstAccessor, BoxSampler>::wsSample (corners read from their
    /// leaf when they share one).
    float valueAt(const OpenMesh::Vec3d& world) const;

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

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
