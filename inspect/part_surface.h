/// @file part_surface.h
/// @brief The surfaces of a solid part for one-sided transparency (thesis chapter VII): the
///        part's outer surface (bores and open cracks included) and the surface of every
///        listed internal void, in one triangle mesh whose faces all point INTO THE MATERIAL.
///
/// Why that orientation: OST discards faces whose normal points away from the camera (render/
/// ray_scene.h). Seen from outside, the near wall of the part has its normal (into the
/// material) pointing away from the camera, so it vanishes; the ray crosses the material and
/// meets a void's near wall, whose normal (into the material, i.e. out of the void) faces the
/// camera: the void shows in place, as a closed blob. Rays that meet no void end on the inside
/// of the part's far wall (its normal faces the camera too). A normal (opaque) render shows the
/// outside of the near wall and hides every internal void. The colon's lumen surface is the
/// same rule seen from the other side: there the normals point into the air (the lumen),
/// here into the material, because here the material is the object and the voids are what the
/// near wall hides.
///
/// Where the surface lies: at the grey-value threshold (partial-volume sub-voxel position),
/// from a narrow-band field (threshold - grey) / half-contrast, in mm, whose sign is forced to
/// agree with the analysis at every voxel centre: negative in the material and in the small
/// voids (counted, not listed: they are filled, so they do not clutter the view), positive in
/// the outside air and in the listed voids. So every listed void has its own closed surface
/// and nothing else does. The mesh is made by makeLumenSurface (volumeToMesh, Taubin smoothing
/// with its orientation guard, the OST checks) on that field.
///
/// Faces are ordered: the outer surface first, then void 1, void 2, ... (VoidInfo::id order),
/// each a contiguous range, so a triangle index (an Embree primitive ID) maps to its void.
#pragma once

#include "surface/lumen_surface.h"
#include "volume/progress.h"
#include "inspect/voids.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <vector>

namespace flyover {

/// Parameters of the inspect surfaces stage.
struct PartSurfaceParams {
    int smoothIterations = 20;       ///< Taubin lambda|mu pairs (0 = none)
    double smoothPassBand = 0.05;    ///< Taubin pass band k_PB, in (0, 1)
    static constexpr int VERSION = 1;
};

/// A contiguous range of faces.
struct FaceRange {
    int64_t first = 0;
    int64_t count = 0;
};

struct PartSurface {
    TriMesh mesh;                    ///< normals into the material; faces ordered as in the file comment
    FaceRange outer;                 ///< the part's outer surface (bores, open cracks)
    std::vector<FaceRange> voids;    ///< index id - 1: the faces of listed void `id`
    /// Faces whose side could not be told (the air beside them is neither outside air nor a
    /// listed void): counted with the outer surface. 0 on a sound analysis.
    int64_t unassignedFaces = 0;
    double halfContrast = 0;         ///< (mean material grey - mean air grey) / 2 in the band
    LumenSurfaceReport report;       ///< extraction, smoothing and the OST checks

    /// The void a face belongs to (0: the outer surface).
    int voidOfFace(int64_t face) const;
};

/// The narrow-band field the part's surface is extracted from (first half of makePartSurface).
/// Holds no reference to the CT, so a caller can free the CT grid (the largest thing in
/// memory: 4 B per voxel) before the mesh is made.
struct PartField {
    openvdb::FloatGrid::Ptr field;               ///< (threshold - grey) / half-contrast, mm, narrow band
    openvdb::BoolGrid::Ptr air;                  ///< outside air and listed voids (the air with a surface)
    openvdb::CoordBBox box;                      ///< the CT's active bounding box
    openvdb::math::Transform::Ptr transform;     ///< the CT's
    double halfContrast = 0;
};

/// @throw ParameterError for bad params (what makePartSurface checks first).
void validatePartSurfaceParams(const PartSurfaceParams& params);

/// The field of the part's surface from the CT and the analysis (see makePartSurface).
PartField makePartField(const openvdb::FloatGrid& ct, const PartAnalysis& analysis, Progress* progress = nullptr);

/// The mesh of a field from makePartField: makePartSurface without the CT. The field's grid is
/// freed once the mesh is extracted.
PartSurface meshPartField(PartField&& field, const PartAnalysis& analysis, const PartSurfaceParams& params,
                          Progress* progress = nullptr);

/// makeLumenSurface's result is regrouped by void through compact arrays (points and face
/// vertex indices), so only one OpenMesh mesh is held at a time.
/// @param ct        the grey-value grid analysePart read (same transform as the analysis grids)
/// @param analysis  analysePart's result (material, outside air, labels of the listed voids)
/// @throw InputError when there is no surface (no material); ParameterError for bad params.
PartSurface makePartSurface(const openvdb::FloatGrid& ct, const PartAnalysis& analysis,
                            const PartSurfaceParams& params, Progress* progress = nullptr);

} // namespace flyover
