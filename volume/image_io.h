/// @file image_io.h
/// @brief Reading scans (NIfTI-1 and NIfTI-2 .nii/.nii.gz/.hdr+.img, NRRD .nrrd/.nhdr, MetaImage
///        .mha/.mhd, DICOM series folders and single DICOM files) and writing dense images,
///        all through ITK's IO except NIfTI-2, whose header flyover reads (ITK 5.2 has
///        no NIfTI-2 reader; see volume/io/nifti2.cpp), and NIfTI voxels (volume/io/nifti1.h) (DICOM through ITK's GDCMImageIO, i.e. GDCM with OpenJPEG
///        and CharLS: uncompressed, JPEG lossless/lossy, JPEG 2000, JPEG-LS, RLE).
///
/// World geometry is LPS millimetres, as ITK reports it (NIfTI's RAS qform/sform is
/// converted by ITK). Nothing here resamples: see volume/ingest.h.
///
/// How voxels are read (memory while a source is open):
/// - streamed by slab: NIfTI-1 and NIfTI-2 voxels are read by flyover a few slices at a time,
///   by pread, or for gzipped files (.nii.gz, .img.gz) inflated by ISA-L while read, on a
///   thread a few slices ahead (volume/io/raw_voxels.h); NIfTI-1 headers are read by ITK.
///   MetaImage (.mha/.mhd) is read by region (ITK's IORegion). Analyze 7.5 headers and scaled
///   double NIfTI-1 voxels are left to ITK (gzipped: first inflated to a temporary file in
///   $TMPDIR). A DICOM series is read file by file.
/// - buffered: NRRD (ITK's NrrdImageIO cannot read a region), compressed MetaImage and
///   multi-frame DICOM files are read once, whole, in their native pixel type (int16: 2
///   bytes per voxel), never as float; heldBytes() says how much.
#pragma once

#include "volume/image.h"

#include <cstdint>
#include <memory>
#include <string>

namespace flyover {

struct ImageReadOptions {
    /// DICOM folder: the Series Instance UID to read; "" = the series with the most slices.
    std::string dicomSeriesUid;
    /// DICOM series: accept missing slices or uneven slice steps (a warning says where);
    /// the volume is then sampled at the true slice positions. Without it they are refused.
    bool allowGaps = false;
};

/// Opens a scan and checks everything that can be checked before reading voxels: format,
/// dimension (3D, one time point), scalar pixel type, spacing (> 0, finite), origin,
/// orthonormal direction cosines, header/data size, and for a DICOM series the slice
/// order (by position along the slice normal, never by file name or Instance Number),
/// uniform slice steps and gantry tilt (detected from the slice positions; corrected by
/// sampling at the true positions, with a warning).
/// @throw InputError naming the file (or folder) and the problem, in one line.
std::unique_ptr<ImageSource> openImage(const std::string& path, const ImageReadOptions& options = {});

/// Reads a whole scan as float (for small images and tests: openImage() + readSlices()).
/// @throw InputError as openImage(); also when the slices are not on a regular lattice
///        (gantry tilt, accepted gaps), which only ingestImage() can resample.
Image3<float> readImage(const std::string& path, const ImageReadOptions& options = {});

/// Writes an image; the format follows the extension (.nii.gz, .nii, .nrrd, .mha, ...).
/// The file is written to a temporary name and renamed into place.
/// @throw InputError when the file cannot be written.
void writeImage(const Image3<int16_t>& image, const std::string& path);
void writeImage(const Image3<uint8_t>& image, const std::string& path);

} // namespace flyover
