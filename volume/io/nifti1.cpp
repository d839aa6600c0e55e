// NIfTI-1 voxels read by flyover after ITK read the header: see nifti1.h.

#include "volume/io/nifti1.h"

#include "volume/io/pixel_convert.h"
#include "volume/io/raw_voxels.h"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>

namespace flyover::imageio {

namespace {

/// The fields of a NIfTI-1 header (348 bytes) that say how the voxels are stored.
struct Nifti1Layout {
    bool swapped = false;
    int16_t dim[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    int16_t datatype = 0, bitpix = 0;
    float slope = 0, inter = 0;
    char magic[4] = {0, 0, 0, 0};
};

template <typename T>
T field(const unsigned char* h, std::size_t offset, bool swapped)
{
    T v;
    unsigned char b[sizeof(T)];
    std::memcpy(b, h + offset, sizeof(T));
    if (swapped) std::reverse(b, b + sizeof(T));
    std::memcpy(&v, b, sizeof(T));
    return v;
}

/// Reads the header (through zlib: .nii.gz too); false when it is not a NIfTI-1 header.
bool readNifti1Layout(const std::string& path, Nifti1Layout& out)
{
    gzFile f = ::gzopen(path.c_str(), "rb");
    if (!f) return false;
    unsigned char h[348];
    const int n = ::gzread(f, h, sizeof h);
    ::gzclose(f);
    if (n != int(sizeof h)) return false;
    if (field<int32_t>(h, 0, false) == 348) out.swapped = false;
    else if (field<int32_t>(h, 0, true) == 348) out.swapped = true;
    else return false;
    for (int d = 0; d < 8; ++d) out.dim[d] = field<int16_t>(h, 40 + 2 * std::size_t(d), out.swapped);
    out.datatype = field<int16_t>(h, 70, out.swapped);
    out.bitpix = field<int16_t>(h, 72, out.swapped);
    out.slope = field<float>(h, 112, out.swapped);
    out.inter = field<float>(h, 116, out.swapped);
    std::memcpy(out.magic, h + 344, 4);
    return true;
}

class Nifti1Source final : public ImageSource {
public:
    Nifti1Source(const std::string& path, const ImageGeometry& g, const RawLayout& layout, const std::string& description,
                 const std::string& warning)
        : mVoxels(path, layout)
    {
        if (!warning.empty()) mWarnings.push_back(warning);
        mName = path;
        mGeometry = g;
        mRegular = true;
        for (int64_t k = 0; k < g.size[2]; ++k) mSliceOriginsMm.push_back(g.worldFromIndex({0, 0, double(k)}));
        mDescription = description;
    }
    void readSlices(int64_t k0, int64_t k1, float* out) override { mVoxels.readSlices(k0, k1, out); }

private:
    RawVoxels mVoxels;
};

} // namespace

std::unique_ptr<ImageSource> openNifti1Voxels(const std::string& path, const ImageGeometry& g, const DataFile& data,
                                              const std::string& itkBitpix, const std::string& description,
                                              const std::string& warning)
{
    if (data.path.empty()) return nullptr;
    std::string lower = path;
    std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    auto endsWith = [&](const char* e) {
        const std::size_t n = std::strlen(e);
        return lower.size() >= n && lower.compare(lower.size() - n, n, e) == 0;
    };
    if (!endsWith(".nii") && !endsWith(".nii.gz") && !endsWith(".hdr")) return nullptr;  // e.g. the .img of a pair
    Nifti1Layout h;
    if (!readNifti1Layout(path, h)) return nullptr;
    const bool single = std::memcmp(h.magic, "n+1\0", 4) == 0, pair = std::memcmp(h.magic, "ni1\0", 4) == 0;
    if (single != (data.path == std::filesystem::path(path)) || (!single && !pair)) return nullptr;  // Analyze 7.5
    if (h.dim[1] != g.size[0] || h.dim[2] != g.size[1] || h.dim[3] != g.size[2]) return nullptr;
    int bytes = 0;
    const IOComponentEnum type = niftiComponentType(h.datatype, bytes);
    if (bytes == 0 || h.bitpix != 8 * bytes || std::atoi(itkBitpix.c_str()) != 8 * bytes) return nullptr;
    // niftilib (and so ITK) takes a non-finite scl_slope or scl_inter as 0.
    const double slope = std::isfinite(h.slope) ? h.slope : 0.0, inter = std::isfinite(h.inter) ? h.inter : 0.0;
    RawLayout layout;
    layout.dataPath = data.path.string();
    layout.compressed = data.compressed;
    layout.offset = data.offset;
    layout.type = type;
    layout.componentBytes = static_cast<std::size_t>(bytes);
    layout.swapped = h.swapped;
    layout.scaled = slope != 0 && !(slope == 1 && inter == 0);  // ITK's NiftiImageIO::MustRescale()
    layout.slope = slope;
    layout.inter = inter;
    layout.size = g.size;
    // Scaled doubles stay double in ITK until the end; leave them to it.
    if (layout.scaled && type == IOComponentEnum::DOUBLE) return nullptr;
    return std::make_unique<Nifti1Source>(path, g, layout, description, warning);
}

} // namespace flyover::imageio
