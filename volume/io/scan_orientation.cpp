#include "volume/scan_orientation.h"

#include "volume/io/gzip_stream.h"
#include "volume/io/io_util.h"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <string>

namespace flyover {

namespace {

using imageio::endsWith;
using imageio::lowerCase;

/// The first `n` decompressed bytes (fewer at the end or on a problem).
std::string headBytes(const std::string& path, std::size_t n)
{
    imageio::GzipStream in(path);
    std::string out(n, '\0');
    out.resize(in.read(out.data(), n));
    return out;
}

template <typename T> T readAt(const std::string& bytes, std::size_t offset, bool swap)
{
    T v{};
    if (offset + sizeof(T) > bytes.size()) return v;
    unsigned char b[sizeof(T)];
    std::memcpy(b, bytes.data() + offset, sizeof(T));
    if (swap) std::reverse(b, b + sizeof(T));
    std::memcpy(&v, b, sizeof(T));
    return v;
}

bool niftiStatesOrientation(const std::string& path)
{
    const std::string h = headBytes(path, 540);
    const int32_t size = readAt<int32_t>(h, 0, false);
    const int32_t swapped = readAt<int32_t>(h, 0, true);
    if (size == 348 || swapped == 348) {
        const bool swap = size != 348;
        // Analyze 7.5 (no "ni1"/"n+1" magic at 344) has no orientation codes.
        if (h.size() < 348 || (h.compare(344, 3, "ni1") != 0 && h.compare(344, 3, "n+1") != 0)) return false;
        return readAt<int16_t>(h, 252, swap) > 0 || readAt<int16_t>(h, 254, swap) > 0;
    }
    if (size == 540 || swapped == 540) {
        const bool swap = size != 540;
        return readAt<int32_t>(h, 344, swap) > 0 || readAt<int32_t>(h, 348, swap) > 0;
    }
    return true;  // not a NIfTI header: the reader says what is wrong
}

/// The text header's lines up to the first empty one (NRRD) or the data (MetaImage), lower-cased.
std::string textHeader(const std::string& path)
{
    std::string h = headBytes(path, 64 * 1024);
    const std::size_t blank = h.find("\n\n");
    if (blank != std::string::npos) h.resize(blank);
    return lowerCase(h);
}

bool hasKey(const std::string& header, const char* key)
{
    for (std::size_t at = header.find(key); at != std::string::npos; at = header.find(key, at + 1))
        if (at == 0 || header[at - 1] == '\n') return true;
    return false;
}

} // namespace

bool scanStatesOrientation(const std::string& path)
{
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) return true;  // a DICOM series
    const std::string name = lowerCase(path);
    if (endsWith(name, ".nii") || endsWith(name, ".nii.gz") || endsWith(name, ".hdr") || endsWith(name, ".hdr.gz"))
        return niftiStatesOrientation(path);
    if (endsWith(name, ".nrrd") || endsWith(name, ".nhdr")) {
        const std::string h = textHeader(path);
        return hasKey(h, "space:") || hasKey(h, "space directions:");
    }
    if (endsWith(name, ".mha") || endsWith(name, ".mhd")) {
        const std::string h = textHeader(path);
        return hasKey(h, "transformmatrix") || hasKey(h, "orientation") || hasKey(h, "rotation") ||
               hasKey(h, "anatomicalorientation");
    }
    return true;
}

} // namespace flyover
