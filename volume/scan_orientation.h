/// @file scan_orientation.h
/// @brief Whether a scan's header states how its voxel axes lie in the patient: a bare mask
///        (a NIfTI with neither qform nor sform, a NRRD without a space) does not, and its
///        world coordinates are then the voxel axes, not LPS. The colon's anatomical segments
///        (colon/anatomy_segments.h) are then found from the path alone.
#pragma once

#include <string>

namespace flyover {

/// False when the header of `path` gives no patient orientation: NIfTI-1/-2 with qform_code
/// and sform_code both 0, Analyze 7.5, NRRD without `space` or `space directions`, MetaImage
/// without TransformMatrix, Orientation, Rotation or AnatomicalOrientation. True otherwise
/// (DICOM, whose Image Orientation (Patient) a CT must have; a file it cannot read: the reader
/// reports that).
bool scanStatesOrientation(const std::string& path);

} // namespace flyover
