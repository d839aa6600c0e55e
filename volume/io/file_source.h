/// @file file_source.h
/// @brief A NIfTI-1, NRRD, MetaImage or single DICOM file opened through one ITK ImageIO
///        (NIfTI-2 is handed to nifti2.h). Internal to volume/.
#pragma once

#include "volume/image.h"
#include "volume/image_io.h"

#include <memory>
#include <string>

namespace flyover::imageio {

/// Opens one file: checks emptiness, the MetaImage header text, probes the header in a child,
/// then reads and checks the header and the data size; gzipped NIfTI that flyover does not
/// read itself is inflated to a temporary file and streamed by slab from there.
/// @throw InputError naming the file.
std::unique_ptr<ImageSource> openFile(const std::string& path, const ImageReadOptions& options);

} // namespace flyover::imageio
