// Scan reading: the entry points of volume/image_io.h. The readers themselves live in
// volume/io/, one file per reader or concern (the one place in flyover that includes ITK):
//   itk_console    IO factory registration, console chatter capture, ITK exception text
//   io_util        names, sizes and message text shared by the readers
//   pixel_convert  native voxel types -> float, NaN/Inf refused
//   geometry_check dimension, pixel type, spacing, origin, direction checks of a header
//   data_size      where a header's voxels are on disk; truncation checks
//   gunzip         inflation to a temporary file (for what ITK reads), temporary folders
//   probe          headers parsed in a forked child first (crash isolation); reader choice
//   metaimage      MetaImage header text check (before MetaIO sees it)
//   raw_voxels     NIfTI voxels by slab: pread, or inflated by ISA-L while read (a thread ahead)
//   gzip_stream    gzip inflation by ISA-L (igzip), read in order
//   nifti1         NIfTI-1 voxels read by flyover once ITK has read the header
//   nifti2         NIfTI-2, read by flyover (ITK 5.2 reads NIfTI-1 only)
//   file_source    one file through ITK: NIfTI-1, NRRD, MetaImage, single DICOM
//   dicom_series   DICOM series folders
//   image_write    writeImage()

#include "volume/image_io.h"

#include "volume/error.h"
#include "volume/io/dicom_series.h"
#include "volume/io/file_source.h"
#include "volume/io/itk_console.h"

#include <algorithm>
#include <filesystem>

namespace fs = std::filesystem;

namespace flyover {

using imageio::openDicomFolder;
using imageio::openFile;
using imageio::registerImageIO;

std::unique_ptr<ImageSource> openImage(const std::string& path, const ImageReadOptions& options)
{
    registerImageIO();
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError(path + ": no such file or directory");
    if (fs::is_directory(path, ec)) return openDicomFolder(path, options);
    return openFile(path, options);
}

Image3<float> readImage(const std::string& path, const ImageReadOptions& options)
{
    auto source = openImage(path, options);
    if (!source->isRegular())
        throw InputError(path + ": the slices are not on a regular lattice (gantry tilt or accepted gaps); "
                                "only ingestImage() can resample them");
    Image3<float> image;
    image.geometry = source->geometry();
    const auto& s = image.geometry.size;
    image.voxels.resize(static_cast<std::size_t>(image.geometry.voxelCount()));
    const int64_t chunk = 16;
    for (int64_t k = 0; k < s[2]; k += chunk)
        source->readSlices(k, std::min(s[2], k + chunk), image.voxels.data() + image.linearIndex(0, 0, k));
    return image;
}

} // namespace flyover
