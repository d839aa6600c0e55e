/// @file lumen_mask.h
/// @brief External lumen masks in, lumen masks out.
///
/// segmentFromMask() turns a label image (TotalSegmentator, a research model, a Slicer
/// segmentation: any file openImage() reads) into the same LumenSegmentation as
/// segmentLumen(), with no thresholding: the lumen is the voxels holding the label.
/// - Geometry: with a reference grid (the study's CT), the output lives on the reference's
///   lattice (the mask is resampled by world position, trilinearly, when its lattice
///   differs); without one, on an isotropic lattice with the mask's origin and axes and its
///   smallest spacing.
/// - Surface: a binary mask's surface lies halfway between its inside and outside voxel
///   centres. The level set starts there and is smoothed (maskSmoothingVoxels) under the
///   constraint that it never crosses a mask voxel centre (inside centres stay inside,
///   outside centres outside): the staircase goes, thin parts stay. A final constant offset
///   makes the level set's sub-voxel volume equal the mask's voxel-count volume, so the
///   lumen neither shrinks nor grows.
///
/// rasterizeLumen() samples a lumen level set at the voxel centres of any image lattice
/// (export onto the original scan's grid, so the mask overlays the CT in other tools).
#pragma once

#include "volume/image.h"
#include "volume/progress.h"
#include "colon/segment.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// What segmentFromMask() read, for the stage report.
struct MaskSummary {
    ImageGeometry geometry;            ///< of the mask file (LPS mm)
    int64_t labelVoxels = 0;           ///< voxels holding the label
    std::vector<int> labelsPresent;    ///< distinct non-zero values (rounded), ascending, at most 64
    bool resampled = false;            ///< the mask's lattice differs from the output grid's
    int64_t voxelsOutsideReference = 0;  ///< label voxels outside the reference grid's bounding box
};

/// @param mask       the label image, opened with openImage() (read slab by slab; only the
///                   label voxels are kept, sparsely)
/// @param params     maskLabel (0 = every voxel > 0.5), maskSmoothingVoxels, bandVoxels
/// @param reference  the study's HU grid (cubic voxels), or nullptr when there is no CT
/// @throw InputError naming the mask: no voxel with the label (the message lists the labels
///        present), slices not on a regular lattice, no overlap with the reference grid;
///        ParameterError for bad parameters.
LumenSegmentation segmentFromMask(ImageSource& mask, const SegmentParams& params,
                                  const openvdb::FloatGrid* reference = nullptr,
                                  Progress* progress = nullptr, MaskSummary* summary = nullptr);

/// The same for a mask already in memory (tests).
LumenSegmentation segmentFromMask(const Image3<float>& mask, const SegmentParams& params,
                                  const openvdb::FloatGrid* reference = nullptr,
                                  Progress* progress = nullptr, MaskSummary* summary = nullptr);

/// Refuses a segmentation that holds no plausible colon: pieces of at least minComponentMl
/// that together are a tube rather than a ball (their volume at least 2 times that of the
/// largest ball inside the lumen, whose radius is the deepest level set value; a ball gives 1,
/// a tube of radius R and length L gives 3L / 4R: a whole colon 10 to 20).
/// @throw InputError starting with `name`: only small pieces, or compact pieces.
void checkPlausibleColon(const LumenSegmentation& seg, const SegmentParams& params, const std::string& name);

/// 1 where the level set is negative at the voxel centre (trilinear interpolation of `sdf`),
/// else 0, on the lattice `geometry`; voxels beyond the level set's active region are 0.
Image3<uint8_t> rasterizeLumen(const openvdb::FloatGrid& sdf, const ImageGeometry& geometry);

} // namespace flyover
