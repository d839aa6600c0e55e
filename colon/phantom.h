/// @file phantom.h
/// @brief Synthetic abdominal CT phantoms with ground truth (design.md "Data").
///
/// Outside air, a body with a fat layer and a bone (spine), two lungs, small-bowel gas
/// pockets away from the colon, and a colon-shaped air tube (rectum, sigmoid, descending,
/// transverse, ascending, cecum; radius about 12-28 mm) with haustral folds and polyps of
/// 3-12 mm radius, some between folds; partial-volume blur and Gaussian noise; int16 HU.
/// Deterministic for a given (size, seed, variant). All positions are LPS world millimetres.
///
/// Variants (off by default; the default phantom is byte-identical with or without them
/// compiled in, because they draw from their own random streams):
/// - fluid: tagged fluid (+300..+600 HU, one value per pool) fills the dependent part of
///   the lumen in three pools (rectum, descending, ascending + cecum): the patient lies
///   supine, so fluid lies posterior (+y) of a flat air-fluid level (a plane y = levelYMm),
///   with a one-voxel partial-volume ramp at the level. The truth lumen is air + fluid.
/// - collapse: one or two stretches of 20-40 mm of the sigmoid have no lumen (soft tissue
///   inside the wall), so the colon falls into 2 or 3 pieces; the truth centerline stays
///   the full path and the truth lists the collapsed arc ranges.
/// - stricture: a stretch of the transverse colon narrows abruptly (shoulders of 3 mm, as an
///   annular tumour's) to a lumen radius of max(3 mm, 1.6 voxels) over 8-12 mm, then widens
///   again, without haustral folds: the colon stays one piece, but its core (the voxels at
///   least half as deep as the deepest nearby) is split there, as a passage 0.8 mm deep
///   splits a real colon's (gca-colon-00020). The truth radii follow the narrowing, and the
///   truth lists it.
/// - colon = false: no colon at all (body, lungs, small-bowel gas, spine): a scan on which
///   segmentation must refuse with a clear message.
/// - redundant: a longer colon (about 2.02 m, 2.03-2.09 m with contacts: an extra sigmoid
///   loop into the right pelvis, a second one high in the left abdomen, a transverse colon
///   that hangs a loop down in front of the small bowel and back up behind it, then sags deep
///   into the right lower abdomen), clear of itself and the body.
/// - touching = N (0..5; at most 2 on the default colon, 5 on the redundant one): N places where two loops far apart along the colon (>= 150 mm of
///   arc) are bent against each other until their walls meet, and the walls between them
///   vanish over a patch 1-3 voxels wide: lumen A and lumen B are face-connected there, in
///   the CT and in the truth mask. The truth lists each contact.
/// - rectalTube: an air-filled catheter (plastic wall) from the air outside the body through
///   the anal verge into the rectum; its lumen joins the colon's air to the outside air.
/// - spacingMm: other voxel sizes over the same field of view (anisotropic slices); the
///   world geometry of the anatomy is the same.
/// - prone (with fluid): the fluid lies anterior of its levels, in the sigmoid and the
///   transverse colon (each pool's arc range runs as far as the lumen reaches below its
///   level); the rectum, posterior then, holds air.
/// - ilealReflux: gas in the terminal ileum, joined to the cecum through the ileocecal
///   valve 50 mm above the cecum's end, and running about 170 mm on into the right pelvis.
/// - orientation: the voxels stored in another order (e.g. "RAS", "LAS", "SLP"), the same
///   world anatomy.
#pragma once

#include "volume/image.h"
#include "volume/vec3.h"

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace flyover {

enum class PhantomSize { Small, Medium, Full };

/// @throw ParameterError for a name other than small, medium, full.
PhantomSize parsePhantomSize(const std::string& name);
const char* phantomSizeName(PhantomSize size);

struct PhantomParams {
    PhantomSize size = PhantomSize::Small;
    uint64_t seed = 1;
    double noiseHu = 15.0;   ///< standard deviation of the added Gaussian noise (HU)
    bool fluid = false;      ///< tagged fluid pools with flat air-fluid levels
    bool collapse = false;   ///< one or two collapsed stretches of the sigmoid
    bool stricture = false;  ///< an abrupt narrowing of the transverse colon
    bool colon = true;       ///< false: no colon (lungs, gas pockets, body only)
    int touching = 0;        ///< contacts between far-apart loops, 0..PHANTOM_MAX_CONTACTS
    bool redundant = false;  ///< extra sigmoid and transverse loops (about 2.0-2.1 m of colon)
    bool rectalTube = false; ///< an air-filled rectal catheter open to the outside air
    bool wideRectum = false; ///< the rectum the widest lumen (radius 30 mm 20-60 mm above the anal end)
    /// The polyps' diameters (mm, each 2-30); unset: the default 6-10 polyps of 6-24 mm;
    /// empty: none.
    std::optional<std::vector<double>> polypDiametersMm{};
    /// Voxel size (mm) along i, j, k; all zero: the size's own spacing. The field of view
    /// stays 400 x 400 x 375 mm centred on the origin (sizes rounded to whole voxels).
    Vec3d spacingMm{0, 0, 0};
    /// With fluid: the patient lies prone, so the tagged fluid pools anterior (-y) of its
    /// levels, in the stretches that hang lowest then (sigmoid, transverse colon).
    bool prone = false;
    /// Gas refluxed through an open ileocecal valve into the terminal ileum: a small-bowel
    /// tube joined to the cecum, whose far end lies farther along the lumen from the rectum
    /// than the cecum's own end.
    bool ilealReflux = false;
    /// How the voxels are stored: three letters naming where index axes i, j, k point
    /// (towards), as nibabel's axis codes: "LPS" (the default: the identity in LPS world),
    /// "RAS" (a prone DICOM's rows and columns, nibabel's canonical), "LAS" (mirrored,
    /// FSL's radiological), or any permutation ("SLP": sagittal slices). The anatomy, the
    /// truth and every world position are the same; only the voxel order and the geometry
    /// change.
    std::string orientation = "LPS";
};

/// The direction matrix (columns: world LPS directions of the index axes) of an orientation
/// code such as "LPS", "RAS" or "SLP".
/// @throw ParameterError naming the code unless it is three letters, one of L/R, one of P/A
///        and one of S/I (case-insensitive).
Mat3d orientationDirection(const std::string& code);

/// Most contacts any colon takes: the default colon has room for 2, the redundant one for 5
/// (makePhantom says so for more).
inline constexpr int PHANTOM_MAX_CONTACTS = 5;
inline constexpr double PHANTOM_MIN_SPACING_MM = 0.5;
inline constexpr double PHANTOM_MAX_SPACING_MM = 5.0;

/// Where two loops of the colon, far apart along it, press together and their lumens join
/// through a hole in the walls (a square channel `widthMm` wide along a world axis).
struct PhantomContact {
    Vec3d positionMm;        ///< centre of the contact patch, midway between the two lumens
    double widthMm = 0;      ///< side of the channel through the walls
    double arcAMm = 0;       ///< arc length of the nearer-to-rectum loop's centerline point
    double arcBMm = 0;       ///< arc length of the other loop's point (arcBMm > arcAMm)
    Vec3d axis;              ///< unit world axis (+-x, y or z) of the channel, from A towards B
    double halfLengthAMm = 0, halfLengthBMm = 0;  ///< channel reach from positionMm into A / B
};

/// An air-filled rectal catheter: a tube along a polyline from its outer end (outside the
/// body) to its open tip in the rectum.
struct PhantomRectalTube {
    std::vector<Vec3d> axisMm;   ///< outer end first, tip last
    double innerRadiusMm = 0;    ///< air lumen
    double outerRadiusMm = 0;    ///< plastic wall outside it
    double wallHu = 0;
    Vec3d tipMm() const { return axisMm.empty() ? Vec3d{} : axisMm.back(); }
};

struct PhantomPolyp {
    Vec3d centerMm;          ///< world LPS mm
    double radiusMm = 0;
    double arcMm = 0;        ///< arc length of the nearest true centerline point from the rectum
    Vec3d outwardDir;        ///< unit direction from the centerline towards the polyp's base
    bool betweenFolds = false;
};

/// A stretch of the colon with no lumen: arc lengths from the rectum end of the centerline.
struct PhantomCollapse {
    double arcStartMm = 0;
    double arcEndMm = 0;
};

/// A narrowing of the lumen: arc lengths from the rectum end of the centerline where the
/// fold-free radius starts to fall and where it is whole again (3 mm shoulders each side),
/// and the radius between the shoulders.
struct PhantomStricture {
    double arcStartMm = 0;
    double arcEndMm = 0;
    double minRadiusMm = 0;
};

/// A pool of tagged fluid: the lumen points whose nearest centerline arc is in
/// [arcStartMm, arcEndMm] and that lie below the level (supine: posterior, y > levelYMm;
/// prone: anterior, y < levelYMm) hold fluid.
struct PhantomFluidPool {
    double arcStartMm = 0;
    double arcEndMm = 0;
    double levelYMm = 0;     ///< LPS y of the flat air-fluid level (mm)
    double hu = 0;           ///< fluid value (HU)
    double downY = 1;        ///< LPS y of gravity's direction: +1 supine (posterior), -1 prone
};

struct PhantomTruth {
    std::vector<Vec3d> centerlineMm;   ///< ordered rectum -> cecum
    std::vector<double> radiusMm;      ///< lumen radius per centerline point (fold-free)
    std::vector<std::string> segment;  ///< anatomical segment name per point
    std::vector<PhantomPolyp> polyps;
    std::vector<PhantomCollapse> collapsed;   ///< sorted by arc; empty unless params.collapse
    std::vector<PhantomStricture> strictures; ///< empty unless params.stricture
    std::vector<PhantomFluidPool> fluidPools; ///< sorted by arc; empty unless params.fluid
    std::vector<PhantomContact> contacts;     ///< sorted by arcAMm; empty unless touching
    bool hasRectalTube = false;
    PhantomRectalTube rectalTube;             ///< when hasRectalTube
    /// With ilealReflux: the terminal ileum's axis (1 mm samples from inside the cecum at the
    /// valve to its blind end), its radius and the colon arc of the valve. Its gas is not in
    /// the truth mask (it is small bowel), it is in the CT, joined to the cecum's.
    std::vector<Vec3d> ileumMm;
    double ileumRadiusMm = 0;
    double ileumValveArcMm = 0;
    double ileumLumenVolumeMl = 0;
    double lumenVolumeMl = 0;          ///< volume of the true lumen mask (air and fluid)
    double fluidVolumeMl = 0;          ///< part of it whose voxel centres hold fluid
    /// The colon's lumen alone: the mask less the rectal tube's air lumen and with the
    /// lumen the tube's wall displaces (equals lumenVolumeMl without a tube).
    double colonLumenVolumeMl = 0;
    double tubeLumenVolumeMl = 0;      ///< mask voxels that are the tube's air lumen
};

struct Phantom {
    Image3<int16_t> ct;          ///< HU
    Image3<uint8_t> truthLumen;  ///< 1 inside the true colon lumen, air or fluid (at voxel centres)
    PhantomTruth truth;
};

/// @throw ParameterError for touching outside 0..PHANTOM_MAX_CONTACTS, a spacing that is not
///        all zero or all in [PHANTOM_MIN_SPACING_MM, PHANTOM_MAX_SPACING_MM], or a negative noise.
Phantom makePhantom(const PhantomParams& params);

/// The image geometry of a phantom: the size's, or the field of view at params.spacingMm.
ImageGeometry phantomImageGeometry(const PhantomParams& params);

} // namespace flyover
