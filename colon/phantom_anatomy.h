/// @file phantom_anatomy.h
/// @brief The analytic anatomy behind makePhantom(): body outline, spine, lungs, the colon
///        (true centerline, radius, rotation-minimising frame, haustral folds, polyps) and
///        small-bowel gas pockets, all in LPS world millimetres, independent of sampling.
///
/// Internal to data/ and its tests; makePhantom() voxelises this description. The body,
/// spine, lungs, colon path and folds are the same for every seed; the seed chooses the
/// polyps and the gas pockets. Building it is serial and cheap (a few milliseconds).
#pragma once

#include "colon/phantom.h"
#include "volume/image.h"
#include "volume/vec3.h"

#include <cstdint>
#include <string>
#include <optional>
#include <vector>

namespace flyover::phantom {

// Tissue values (HU).
inline constexpr double AIR_HU = -1000.0;
inline constexpr double LUNG_HU = -850.0;
inline constexpr double FAT_HU = -100.0;
inline constexpr double SOFT_TISSUE_HU = 40.0;
inline constexpr double DISC_HU = 80.0;
inline constexpr double CANCELLOUS_BONE_HU = 700.0;
inline constexpr double CORTICAL_BONE_HU = 1200.0;

// Body: an extruded (along z) cross-section made of two half-ellipses sharing the
// left-right axis y = 0: anterior (y < 0) and posterior (y > 0) half-depths differ.
inline constexpr double BODY_HALF_WIDTH_MM = 170.0;      ///< along x (left-right)
inline constexpr double BODY_ANTERIOR_DEPTH_MM = 130.0;  ///< from y = 0 towards -y
inline constexpr double BODY_POSTERIOR_DEPTH_MM = 120.0; ///< from y = 0 towards +y
inline constexpr double SUBCUTANEOUS_FAT_MM = 17.0;

// Vertebral column: a cylinder along z with a cortical shell and intervertebral discs.
inline constexpr double SPINE_CENTER_Y_MM = 65.0;  ///< x = 0
inline constexpr double SPINE_RADIUS_MM = 20.0;
inline constexpr double SPINE_CORTEX_MM = 2.5;
inline constexpr double DISC_PERIOD_MM = 32.0;
inline constexpr double DISC_THICKNESS_MM = 6.0;

// Colon wall and the pericolic fat that embeds it.
inline constexpr double COLON_WALL_MM = 3.0;
inline constexpr double PERICOLIC_FAT_MM = 10.0;

/// Arc separation (mm) above which two centerline points belong to non-adjacent parts.
inline constexpr double NON_ADJACENT_ARC_MM = 100.0;
/// Least gap (mm) between the outer wall surfaces of non-adjacent parts of the colon.
inline constexpr double MIN_WALL_GAP_MM = 15.0;

struct Ellipsoid {
    Vec3d centerMm;
    Vec3d semiAxesMm;
    Mat3d axes = identityMat3();  ///< columns: world directions of the semi-axes
    double volumeMl() const;
    /// Signed distance (mm), first-order accurate near the surface, exact in sign.
    double signedDistanceMm(const Vec3d& p) const;
};

/// A semilunar haustral fold: a thin ridge in the plane normal to the centerline at
/// `arcMm`, protruding from the wall into the lumen by `depthMm` at `centerAngleRad`
/// and tapering to zero at +-`halfSectorRad` from it.
struct HaustralFold {
    double arcMm = 0;
    int index = 0;               ///< centerline sample at arcMm
    double thicknessMm = 4;
    double depthMm = 0;          ///< greatest protrusion from the (fold-free) lumen wall
    double tubeRadiusMm = 0;     ///< fold-free radius at arcMm
    double centerAngleRad = 0;   ///< in the rotation-minimising frame (normal, binormal)
    double halfSectorRad = 0;
    /// Signed distance (mm) to the fold solid: a ridge with a rounded free edge.
    /// Points outside the angular sector are reported far away (+1e9).
    double signedDistanceMm(const Vec3d& p, const Vec3d& centerMm, const Vec3d& tangent,
                            const Vec3d& normal, const Vec3d& binormal) const;
};

struct PhantomAnatomy {
    // Colon, sampled every 1 mm of arc length from the rectum end to the cecum end.
    std::vector<Vec3d> centerlineMm;
    std::vector<double> radiusMm;      ///< fold-free lumen radius
    std::vector<std::string> segment;
    std::vector<Vec3d> tangent, normal, binormal;  ///< rotation-minimising frame
    double stepMm = 1.0;
    std::vector<HaustralFold> folds;   ///< sorted by arcMm
    std::vector<PhantomPolyp> polyps;  ///< sorted by arcMm

    Ellipsoid lungs[2];                ///< right (-x), left (+x)
    std::vector<Ellipsoid> gasPockets; ///< small-bowel gas

    // Variants (empty for the default phantom): see addCollapses() and addFluidPools().
    std::vector<PhantomCollapse> collapsed;   ///< sorted by arc
    std::vector<PhantomStricture> strictures; ///< sorted by arc
    std::vector<PhantomFluidPool> fluidPools; ///< sorted by arc
    std::vector<PhantomContact> contacts;     ///< sorted by arcAMm; see AnatomyOptions
    /// Arc half-widths (mm) of the bends that brought each contact's loops together:
    /// non-adjacent walls may meet only inside these windows.
    std::vector<double> contactWindowMm;
    bool hasRectalTube = false;
    PhantomRectalTube rectalTube;
    /// The `ilealReflux` variant: the gas-filled terminal ileum (1 mm samples from inside the
    /// cecum at the ileocecal valve to its blind end; empty without it).
    std::vector<Vec3d> ileumMm;
    double ileumRadiusMm = 0;
    double ileumValveArcMm = 0;  ///< arc of the colon centerline sample it leaves from
    /// The redundant or touching colon: its bends may be a little tighter (curvature times
    /// outer radius up to 0.95 instead of 0.8; the wall still never folds over).
    bool variantPath = false;

    double lengthMm() const { return stepMm * double(centerlineMm.size() - 1); }
};

/// The anatomy for a seed. Same body, colon and folds for every seed.
/// @throw std::logic_error when a built-in invariant fails (a programming error).
PhantomAnatomy buildPhantomAnatomy(uint64_t seed);

/// Variants that change the colon itself (its path, its folds, where polyps may go).
struct AnatomyOptions {
    bool redundant = false;   ///< the longer colon (REDUNDANT control points)
    int touching = 0;         ///< contacts, 0..PHANTOM_MAX_CONTACTS
    /// Voxel size (mm) along x, y, z of the image the anatomy will be sampled on: contact
    /// channels are 1.3-1.7 of the coarser voxel across them, so 1-3 voxels wide.
    Vec3d voxelMm{1, 1, 1};
    bool rectalTube = false;
    /// The rectum the widest lumen (radius 30 mm from 20 to 60 mm above the anal end, easing
    /// back to the colon's own by 100 mm), as in a well-distended real colon.
    bool wideRectum = false;
    /// The polyps' diameters (mm), placed by the default rules but none required between
    /// folds; unset: the default 6-10 of 6-24 mm. Empty: no polyps.
    std::optional<std::vector<double>> polypDiametersMm{};
};

/// With all options off this is buildPhantomAnatomy(seed), bit for bit. Contacts are drawn
/// from a random stream of their own.
/// @throw std::logic_error when a built-in invariant fails (a programming error).
PhantomAnatomy buildPhantomAnatomy(uint64_t seed, const AnatomyOptions& options);

/// Signed distance (mm) to the channel of a contact (a box along contact.axis), negative inside.
double contactSignedDistanceMm(const PhantomContact& contact, const Vec3d& p);

/// Distance (mm) from p to the rectal tube's axis polyline, and the signed distance to the
/// plane that cuts the tube open at its tip (positive beyond the tip). The tube's wall is
/// max(distance - outer radius, cut) < 0; its air lumen max(distance - inner radius, cut) < 0.
struct TubeDistance {
    double axisMm = 1e9;
    double beyondTipMm = 0;
};
TubeDistance rectalTubeDistance(const PhantomRectalTube& tube, const Vec3d& p);

/// The rectal tube of the `rectalTube` variant for an anatomy's centerline.
PhantomRectalTube makeRectalTube(const PhantomAnatomy& anatomy);

/// The `collapse` variant: one or two stretches of 20-40 mm of the sigmoid lose their lumen,
/// at least 10 mm (plus the polyp radius) away from every polyp; with two, the middle piece
/// is 100-140 mm of sigmoid (about 60 mL). Drawn from a random stream of its own, so the
/// rest of the anatomy does not change.
void addCollapses(PhantomAnatomy& anatomy, uint64_t seed);

/// The `stricture` variant: a stretch of the transverse colon, at least 10 mm (plus the polyp
/// radius) from every polyp and 30 mm from every contact, narrows over 3 mm shoulders to a
/// radius of max(3 mm, 1.6 x voxelMm) kept over 8-12 mm (anatomy.radiusMm follows it), and
/// loses its haustral folds. Own random stream.
void addStricture(PhantomAnatomy& anatomy, uint64_t seed, double voxelMm);

/// The `fluid` variant: tagged fluid (+300..+600 HU) pools posterior of flat levels in the
/// rectum, the descending colon and the ascending colon with the cecum, each 25-45% of the
/// lumen diameter deep where the colon lies lowest (most posterior). Own random stream.
/// prone: the patient lies prone, so the pools lie anterior of their levels, in the sigmoid
/// and the transverse colon, each from where its colon lies lowest (most anterior) along
/// the arcs where the lumen reaches below the level; the same random draws.
void addFluidPools(PhantomAnatomy& anatomy, uint64_t seed, bool prone = false);

/// The `ilealReflux` variant: gas refluxed through an open ileocecal valve fills the
/// terminal ileum, a tube of radius 11 mm and about 170 mm that leaves the cecum's medial
/// wall 50 mm above its end and loops down into the right pelvis, clear of the rest of the
/// colon (the same cecum on every colon variant); small-bowel gas pockets in its way are
/// dropped. Deterministic.
/// @throw std::logic_error when it would come near another loop, the spine or the skin.
void addIleum(PhantomAnatomy& anatomy);

/// Image geometry of a phantom size: FOV 400 x 400 x 375 mm centred on the world origin.
ImageGeometry phantomGeometry(PhantomSize size);

/// Signed distance (mm, negative inside) to the skin, first-order accurate near it.
double bodySignedDistanceMm(double xMm, double yMm);
/// Signed distance (mm) to the inner boundary of the subcutaneous fat.
double bodyInnerSignedDistanceMm(double xMm, double yMm);

/// Smallest gap (mm) between the outer wall surfaces (lumen + COLON_WALL_MM) of two
/// centerline points more than NON_ADJACENT_ARC_MM apart in arc length; reports where.
struct ColonClearance {
    double gapMm = 1e9;
    std::size_t i = 0, j = 0;
};
ColonClearance colonSelfClearance(const PhantomAnatomy& anatomy);
/// The same, skipping the pairs inside a contact's windows (|i - arcA|, |j - arcB| within
/// contactWindowMm): the clearance of the parts that must not touch.
ColonClearance colonClearanceOutsideContacts(const PhantomAnatomy& anatomy);

/// splitmix64 finaliser: a counter-based hash used for all per-voxel randomness.
inline uint64_t splitmix64(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

} // namespace flyover::phantom
