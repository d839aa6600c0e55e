// Data files and their sizes: see data_size.h.

#include "volume/io/data_size.h"

#include "volume/error.h"
#include "volume/io/io_util.h"
#include "volume/io/itk_console.h"

#include <itkMetaDataObject.h>
#include <itkMetaImageIO.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <sstream>

namespace fs = std::filesystem;

namespace flyover::imageio {

std::string metaString(const itk::ImageIOBase& io, const std::string& key)
{
    std::string v;
    itk::ExposeMetaData<std::string>(io.GetMetaDataDictionary(), key, v);
    return trim(v);
}

DataFile dataFileOf(itk::ImageIOBase& io, const std::string& path)
{
    DataFile f;
    uint64_t voxels = 1;
    for (unsigned d = 0; d < io.GetNumberOfDimensions(); ++d) voxels *= io.GetDimensions(d);
    const std::string format = formatOfIo(io);
    const std::string lower = lowerCase(path);
    if (format == "NIfTI") {
        const std::string bitpix = metaString(io, "bitpix"), offset = metaString(io, "vox_offset");
        if (bitpix.empty() || offset.empty()) return f;
        f.bytes = voxels * static_cast<uint64_t>(std::max(0L, std::atol(bitpix.c_str()))) / 8;
        f.offset = static_cast<uint64_t>(std::max(0.0, std::atof(offset.c_str())));
        if (endsWith(lower, ".nii")) f.path = path;
        else if (endsWith(lower, ".nii.gz")) { f.path = path; f.compressed = true; }
        else if (endsWith(lower, ".hdr") || endsWith(lower, ".img") || endsWith(lower, ".img.gz")) {
            const fs::path base = fs::path(path).parent_path() / fs::path(path).stem();
            fs::path img = endsWith(lower, ".img.gz") ? fs::path(path) : base;
            if (!endsWith(lower, ".img.gz")) {
                img.replace_extension(".img");
                if (!fs::exists(img) && fs::exists(img.string() + ".gz")) img = img.string() + ".gz";
            }
            f.path = img;
            f.compressed = endsWith(lowerCase(img.string()), ".gz");
        }
    } else if (format == "MetaImage") {
        auto* meta = dynamic_cast<itk::MetaImageIO&>(io).GetMetaImagePointer();
        const std::string name = meta->ElementDataFileName();
        f.bytes = voxels * io.GetComponentSize() * io.GetNumberOfComponents();
        f.compressed = meta->CompressedData();
        if (lowerCase(name) == "local") {
            f.path = path;  // offset: the header's length (unknown)
        } else if (name.find('%') == std::string::npos && lowerCase(name).rfind("list", 0) != 0 && !name.empty()) {
            f.path = fs::path(path).parent_path() / name;
            f.offset = static_cast<uint64_t>(std::max(0, meta->HeaderSize()));
        } else {
            // File lists and printf-style patterns: ITK 5.2's MetaIO reads past its buffers on
            // malformed ones (found by fuzzing), and scans do not use them: refuse.
            std::string shown;
            for (char c : name.substr(0, 40)) shown += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
            throw InputError(path + ": ElementDataFile '" + shown + (name.size() > 40 ? "...'" : "'") +
                             " is a file list or pattern, which is not supported (use LOCAL or one data file)");
        }
    }
    return f;
}

void checkDataSize(const DataFile& f, const std::string& path, const ImageGeometry& g, const std::string& typeName)
{
    if (f.path.empty() || f.compressed) return;
    if (!fs::exists(f.path))
        throw InputError(path + ": its voxel data file " + f.path.string() + " does not exist");
    const uint64_t have = fileBytes(f.path);
    if (have < f.offset + f.bytes) {
        std::ostringstream os;
        os << path << ": header/data size mismatch: the header describes " << sizeText(g.size) << " "
           << typeName << " voxels (" << f.bytes << " bytes";
        if (f.offset > 0) os << " after a " << f.offset << "-byte header";
        os << ") but " << (f.path == fs::path(path) ? "the file" : f.path.filename().string())
           << " holds " << have << " bytes (truncated?)";
        throw InputError(os.str());
    }
}

} // namespace flyover::imageio
