/// @file mesh_checks.h
/// @brief Topology and measures of a triangle mesh (OpenMesh only, no grid): components,
///        genus, boundary loops, manifoldness, degenerate faces, area, enclosed volume, and
///        the orientation of each component judged by the sign of its enclosed volume.
///
/// What this does not check: whether normals agree with a level set (that needs the grid:
/// see checkFaceOrientation in extract_surface.h). Non-manifold EDGES cannot exist in an
/// OpenMesh halfedge mesh (add_face refuses them); extractSurface counts them in its input
/// triangles instead (MeshStats::nonManifoldEdges).
#pragma once

#include "surface/mesh_types.h"

#include <cstdint>
#include <vector>

namespace flyover {

/// One edge-connected component of a mesh.
struct MeshComponent {
    int64_t vertices = 0;
    int64_t edges = 0;
    int64_t faces = 0;
    int64_t boundaryLoops = 0;      ///< 0 for a closed component
    int64_t genus = 0;              ///< from chi = V - E + F = 2 - 2 genus - boundaryLoops
    double areaMm2 = 0;
    /// Signed enclosed volume (mm^3), POSITIVE when the normals point into the enclosed
    /// region. Boundary loops are capped by a fan to the loop's centroid, so an open tube
    /// gets the volume of the capped tube.
    double enclosedVolumeMm3 = 0;
    /// How many other components enclose this one (generalised winding number of one of its
    /// vertices). An even depth bounds lumen from outside (normals point into the enclosed
    /// region, volume > 0); an odd depth is an island inside the lumen (volume < 0).
    int nestingDepth = 0;

    bool isClosed() const { return boundaryLoops == 0; }
    /// True when the sign of the enclosed volume is the one inward normals give at this depth.
    bool hasInwardVolumeSign() const
    {
        return nestingDepth % 2 == 0 ? enclosedVolumeMm3 > 0 : enclosedVolumeMm3 < 0;
    }
};

/// Whole-mesh report (the manifest's record of the surface).
struct MeshCheck {
    int64_t vertices = 0;
    int64_t edges = 0;
    int64_t faces = 0;
    int64_t components = 0;
    int64_t closedComponents = 0;
    int64_t genus = 0;                 ///< sum over components
    int64_t boundaryLoops = 0;         ///< open loops (where the scan bounds cut the lumen)
    int64_t boundaryEdges = 0;
    int64_t nonManifoldVertices = 0;   ///< vertices whose faces form more than one fan
    int64_t isolatedVertices = 0;      ///< vertices without a face
    int64_t degenerateFaces = 0;       ///< area below float resolution (see isDegenerateFace)
    /// Components whose enclosed volume has the wrong sign for their nesting depth, i.e.
    /// components oriented outward as a whole.
    int64_t misorientedComponents = 0;
    double areaMm2 = 0;
    double enclosedVolumeMm3 = 0;      ///< sum of the components' signed volumes
    std::vector<MeshComponent> componentList;  ///< largest (by faces) first

    bool isManifold() const { return nonManifoldVertices == 0; }
    bool isClosed() const { return boundaryEdges == 0; }
};

/// Measures `mesh`. Cost: linear in its size, plus, per component d whose bounding box holds
/// others: one solid-angle winding number over d's faces per held component when they are
/// few, else one ray-crossing grid over d's faces (ray_winding.h) and a few faces per held
/// component. Both give the same integer winding number (the crossing count answers only
/// when no crossing is within rounding of an edge; otherwise the solid-angle sum decides).
MeshCheck checkMesh(const TriMesh& mesh);

/// Area and enclosed volume (capped, summed over components) of a mesh.
struct MeshMeasures {
    double areaMm2 = 0;
    double enclosedVolumeMm3 = 0;
};

/// The areaMm2 and enclosedVolumeMm3 checkMesh() reports for `mesh` with its vertices at
/// `points` (indexed by vertex; same connectivity), bit for bit the same arithmetic, without
/// the nesting test. Lets the measures of a mesh's earlier shape (the extracted surface before
/// smoothing) be taken later from a copy of its positions only.
MeshMeasures measureMesh(const TriMesh& mesh, const std::vector<TriMesh::Point>& points);

/// A triangle is degenerate when twice its area is below 1e-6 times its longest edge
/// squared: its smallest height is under a millionth of its size, below what float
/// coordinates resolve reliably, so its normal means nothing. NaN-safe (NaN: degenerate).
inline bool isDegenerateTriangle(double twiceArea, double longestEdgeSqr)
{
    return !(twiceArea > 1e-6 * longestEdgeSqr);
}
bool isDegenerateFace(const TriMesh& mesh, TriMesh::FaceHandle face);

/// Mean angle (degrees) between the normals of the two faces of each interior edge: the
/// roughness that smoothing removes (a voxel staircase has many edges near 45 or 90 degrees,
/// a smooth surface sampled at edge length h with curvature radius r about h / r radians).
/// Edges next to a degenerate face are left out. @return 0 without interior edges
double meanDihedralAngleDeg(const TriMesh& mesh);
/// The same with the vertices at `points` (indexed by vertex) instead of the mesh's.
double meanDihedralAngleDeg(const TriMesh& mesh, const std::vector<TriMesh::Point>& points);

} // namespace flyover
