/// @file ray_winding.h
/// @brief Winding numbers of many points with respect to one closed triangle surface, by
///        counting the signed crossings of a ray: checkMesh's nesting test for components that
///        hold many others (a part's outer surface around hundreds of voids).
///
/// Why: the generalised winding number (a solid-angle sum over every face) costs O(faces) per
/// point, so nesting hundreds of voids in an outer surface of millions of faces costs
/// O(voids x faces) (minutes at 1024^3). For a CLOSED surface the winding number is an
/// integer and equals the signed number of times a ray from the point crosses it (+1 where
/// the surface faces one way along the ray, -1 the other). The faces are binned once into a
/// 2D grid across the ray direction (O(faces)); each point then tests only the faces of its
/// cell.
///
/// Exactness: the answer is the exact integer or nothing. Whenever the ray passes within a
/// tolerance (1e-9 of the surface's size) of an edge or vertex of a face it meets, or the
/// point lies that close to a face, or a face is degenerate across the ray, the count could
/// be wrong by rounding, so winding() returns no answer and the caller asks another
/// direction or falls back to the solid-angle sum. The ray direction is not along any axis,
/// so marching-cubes vertices (which share lattice coordinates) do not line up with it.
#pragma once

#include "surface/mesh_types.h"

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

namespace flyover {

class RayWindingCounter {
public:
    using Vec3d = OpenMesh::Vec3d;
    using Triangle = std::array<Vec3d, 3>;

    /// Bins `faces` of `mesh` and the extra triangles `caps` (fans closing boundary loops)
    /// for rays along `direction` (normalised here). The mesh must outlive the counter.
    RayWindingCounter(const TriMesh& mesh, const std::vector<TriMesh::FaceHandle>& faces,
                      const std::vector<Triangle>& caps, const Vec3d& direction);

    /// The winding number of `p` (the signed count of crossings of the ray p + t direction,
    /// t > 0), or nothing when a crossing is too close to call (see the file comment).
    std::optional<int> winding(const Vec3d& p) const;

    /// Three fixed directions, none along an axis nor in a coordinate plane, for retries.
    static const std::array<Vec3d, 3>& directions();

private:
    Triangle triangle(std::size_t i) const;
    /// (s, t, h): across the ray (s, t) and along it (h).
    Vec3d project(const Vec3d& p) const { return Vec3d(OpenMesh::dot(p, mE1), OpenMesh::dot(p, mE2), OpenMesh::dot(p, mDir)); }
    bool cellOf(double s, double t, int64_t& cell) const;

    const TriMesh& mMesh;
    const std::vector<TriMesh::FaceHandle>& mFaces;
    const std::vector<Triangle>& mCaps;
    Vec3d mDir, mE1, mE2;
    double mTol = 0;                 ///< distances below this are too close to call
    double mLoS = 0, mLoT = 0, mCell = 1;
    int64_t mNs = 1, mNt = 1;
    std::vector<uint64_t> mStart;    ///< per cell: its first entry in mItems (CSR)
    std::vector<uint32_t> mItems;    ///< triangle indices (faces, then caps)
};

} // namespace flyover
