/// @file local_first_pair.h
/// @brief Internal to pipeline/ (issue 15): the first fly-over pair rendered from a surface
///        made only around its cameras, as soon as the contact cut and the centerline are
///        known, before the whole surface is made. It is shown only when no ray of it can meet
///        what the local surface lacks; inside its box the local surface is the whole one's
///        (measured: see below), and the frames step confirms the pixels.
///
/// How. The lumen level set is clipped to a box round the first centerline point (the exact
/// box, half-width 2 cap with cap = 2 D + 5 mm at the first point, at least 40 mm; widened on
/// every side by a margin of 40 voxels, at least 20 mm) and meshed with the mesh stage's own makeLumenSurface. The extraction is local to
/// each cell, and the Taubin smoothing moves a vertex by what its rings within 2 x iterations
/// steps hold, with weights that fall off fast: measured on the full phantom, every vertex
/// farther than ~17 mm from the clip is bit for bit the whole mesh's (bench/local_mesh_probe),
/// so the margin keeps the clip's effect outside the exact box. The pair is then certified, or
/// not shown:
/// - every fan ray of the frame radius R starts in the exact box and meets the surface (or ends)
///   inside it, so R is the whole scene's;
/// - both near planes lie inside the exact box; every pixel's ray that meets the surface meets
///   it inside the box (its way there lies in the convex box, where the two surfaces agree);
/// - every ray that meets nothing passes no active leaf (8^3 voxels, widened by 2 voxels for
///   the smoothing) of the level set that is not wholly inside the exact box: there the whole
///   surface has no triangle either.
/// It is tried only when the clip box holds at most 35% of the level set's leaves: for a small
/// lumen the whole mesh is about as near.
/// The frames step still renders the pair from the whole scene and replaces it, saying so,
/// should a pixel differ (as for its own first pair): a last guard, not the certificate.
///
/// What it does not do: supersampled frames (only the pixel-centre rays are checked) and
/// decimated meshes (decimation is not local) are left to the frames step.
#pragma once

#include "render/camera.h"
#include "render/flyover_path.h"
#include "render/render_view.h"
#include "surface/extract_surface.h"
#include "volume/centerline_types.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstddef>
#include <string>

namespace flyover {

struct LocalFirstPair {
    bool certified = false;
    std::string reason;  ///< why it was not certified (empty when it was)
    RgbImage pair;       ///< the pair image, as renderPair gives it
    std::array<Camera, 2> cameras{};
    double frameRadiusMm = 0;
    BoxMm exactBox, clipBox;
    std::size_t localTriangles = 0;
    std::size_t uncertainPixels = 0;  ///< rays that met nothing but might meet the whole surface
    std::size_t checkLeaves = 0;      ///< level-set leaves the rays that met nothing were checked against
    double clipLeafFraction = 0;      ///< share of the level set's leaves in the clip box
    double meshSeconds = 0, radiusSeconds = 0, renderSeconds = 0, checkSeconds = 0;
};

/// Whether the frames of `ro` and the mesh of `mesh` allow a local first pair at all.
bool localFirstPairApplies(const MeshParams& mesh, const RenderOptions& ro);

/// The first pair at centerline point `index` from the surface of `sdf` around it (see the file
/// comment). Never throws for what the data holds (an empty clip, a ray leaving the box): it
/// returns certified = false with the reason.
LocalFirstPair localFirstPair(const openvdb::FloatGrid& sdf, const Centerline& centerline, std::size_t index,
                              const MeshParams& mesh, const FlyoverParams& flyover, const RenderOptions& ro);

} // namespace flyover
