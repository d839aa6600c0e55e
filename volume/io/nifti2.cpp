// ITK 5.2 (Debian 12) reads NIfTI-1 only. Debian's nifticlib 3.0 (libnifti2) reads NIfTI-2,
// but it exports about a hundred nifti_* functions under the same names as ITK's bundled
// NIfTI-1 library (libITKniftiio) with other struct layouts (int64 dims, double fields):
// in one process one library's calls would resolve to the other's functions. So only the
// header struct is taken from nifticlib (nifti2.h: nifti_2_header, 540 bytes, packed) and
// its fields are interpreted here exactly as ITK 5.2's NiftiImageIO interprets the same
// fields of a NIfTI-1 header (tests/volume/image_io_test.cpp checks the two agree on
// sform-only, qform-only, both, neither, oblique, flipped, metre and micron headers):
// - both qform_code and sform_code 0: origin 0, identity directions, spacing pixdim;
// - the sform, when sform_code > 0, its columns are orthogonal and their lengths match
//   pixdim, and the qform is absent, or sform_code is 1 (scanner), or the two agree;
// - else the qform (quaternion b, c, d; qfac = pixdim[0]; offsets) when qform_code > 0;
// - else (an sform with shear or scaling that does not match pixdim, and no qform): refused.
// NIfTI's RAS is turned into LPS by negating x and y; metre and micron units are scaled to
// mm. Voxels: int8..uint64, float32, float64, either byte order, scl_slope/scl_inter applied
// (slope 0 means none), streamed by slab (gzip inflated while read: raw_voxels.h).

#include "volume/io/nifti2.h"

#include "volume/error.h"
#include "volume/io/geometry_check.h"
#include "volume/io/io_util.h"
#include "volume/io/pixel_convert.h"
#include "volume/io/raw_voxels.h"

#include <nifti/nifti2.h>  // the NIfTI-2 header struct only (see above)
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <vector>


namespace fs = std::filesystem;

namespace flyover::imageio {

/// NIfTI-2 begins with sizeof_hdr = 540 (either byte order), NIfTI-1 with 348.
bool isNifti2(const std::string& path)
{
    gzFile f = ::gzopen(path.c_str(), "rb");  // reads plain files transparently
    if (!f) return false;
    unsigned char b[4] = {0, 0, 0, 0};
    const int n = ::gzread(f, b, 4);
    ::gzclose(f);
    if (n != 4) return false;
    const uint32_t le = b[0] | (b[1] << 8) | (b[2] << 16) | (uint32_t(b[3]) << 24);
    const uint32_t be = b[3] | (b[2] << 8) | (b[1] << 16) | (uint32_t(b[0]) << 24);
    return le == 540 || be == 540;
}

namespace {

struct Nifti2Header {
    nifti_2_header h{};
    bool swapped = false;
};

template <typename T>
void swapBytes(T& v)
{
    auto* b = reinterpret_cast<unsigned char*>(&v);
    std::reverse(b, b + sizeof(T));
}

void swapNifti2Header(nifti_2_header& h)
{
    swapBytes(h.sizeof_hdr);
    swapBytes(h.datatype);
    swapBytes(h.bitpix);
    for (auto& v : h.dim) swapBytes(v);
    for (auto& v : h.pixdim) swapBytes(v);
    swapBytes(h.vox_offset);
    swapBytes(h.scl_slope);
    swapBytes(h.scl_inter);
    swapBytes(h.qform_code);
    swapBytes(h.sform_code);
    for (double* v : {&h.quatern_b, &h.quatern_c, &h.quatern_d, &h.qoffset_x, &h.qoffset_y, &h.qoffset_z}) swapBytes(*v);
    for (int c = 0; c < 4; ++c) {
        swapBytes(h.srow_x[c]);
        swapBytes(h.srow_y[c]);
        swapBytes(h.srow_z[c]);
    }
    swapBytes(h.xyzt_units);
    swapBytes(h.intent_code);
}

/// Reads the first 540 bytes (through zlib, so .nii.gz too) and checks size and magic.
Nifti2Header readNifti2Header(const std::string& path)
{
    Nifti2Header r;
    gzFile f = ::gzopen(path.c_str(), "rb");
    if (!f) throw InputError(path + ": cannot open: " + std::strerror(errno));
    const int n = ::gzread(f, &r.h, sizeof(nifti_2_header));
    ::gzclose(f);
    if (n != int(sizeof(nifti_2_header)))
        throw InputError(path + ": NIfTI-2 header is truncated (" + std::to_string(std::max(n, 0)) + " of 540 bytes)");
    if (r.h.sizeof_hdr != 540) {
        swapNifti2Header(r.h);
        r.swapped = true;
    }
    if (r.h.sizeof_hdr != 540) throw InputError(path + ": not a NIfTI-2 header (sizeof_hdr is not 540)");
    const bool single = std::memcmp(r.h.magic, "n+2\0", 4) == 0, pair = std::memcmp(r.h.magic, "ni2\0", 4) == 0;
    if (!single && !pair) throw InputError(path + ": NIfTI-2 header has no valid magic ('n+2' or 'ni2')");
    return r;
}

std::string nifti2TypeName(int datatype)
{
    switch (datatype) {
    case 32: return "complex64";
    case 128: return "RGB24";
    case 1536: return "float128";
    case 1792: return "complex128";
    case 2048: return "complex256";
    case 2304: return "RGBA32";
    default: return "datatype " + std::to_string(datatype);
    }
}

/// Geometry from a NIfTI-2 header's fields, by ITK 5.2's rules for the same NIfTI-1 fields
/// (see the comment above).
ImageGeometry nifti2Geometry(const nifti_2_header& h, const std::string& path)
{
    ImageGeometry g;
    for (int c = 0; c < 3; ++c) g.size[c] = h.dim[c + 1];
    double unit = 1.0;  // to mm
    switch (h.xyzt_units & 0x07) {
    case 1: unit = 1000.0; break;  // NIFTI_UNITS_METER
    case 3: unit = 0.001; break;   // NIFTI_UNITS_MICRON
    default: break;                // mm or unknown: mm
    }
    for (int c = 0; c < 3; ++c) g.spacingMm[c] = h.pixdim[c + 1] * unit;
    if (h.qform_code <= 0 && h.sform_code <= 0) return g;  // origin 0, identity (as ITK)

    const double* srow[3] = {h.srow_x, h.srow_y, h.srow_z};
    auto lps = [](int r) { return r < 2 ? -1.0 : 1.0; };
    bool sformUsable = false;
    Mat3d sdir{};
    if (h.sform_code > 0) {
        sformUsable = true;
        Vec3d len;
        for (int c = 0; c < 3; ++c) {
            len[c] = std::sqrt(srow[0][c] * srow[0][c] + srow[1][c] * srow[1][c] + srow[2][c] * srow[2][c]);
            if (!(len[c] > 0) || !std::isfinite(len[c])) sformUsable = false;
            else if (std::fabs(len[c] - h.pixdim[c + 1]) > 1e-4 * std::max(1.0, std::fabs(h.pixdim[c + 1])))
                sformUsable = false;  // scaling that pixdim does not describe
        }
        if (sformUsable) {
            for (int c = 0; c < 3; ++c)
                for (int r = 0; r < 3; ++r) sdir[r][c] = srow[r][c] / len[c];
            for (int a = 0; a < 3; ++a)
                for (int b = a + 1; b < 3; ++b) {
                    double d = 0;
                    for (int r = 0; r < 3; ++r) d += sdir[r][a] * sdir[r][b];
                    if (std::fabs(d) > 1e-4) sformUsable = false;  // shear
                }
        }
    }
    // The qform, as nifticlib's quatern_to_mat44 builds it.
    Mat3d qdir{};
    {
        double b = h.quatern_b, c = h.quatern_c, d = h.quatern_d;
        double a = 1.0 - (b * b + c * c + d * d);
        if (a < 1e-7) {
            const double s = 1.0 / std::sqrt(b * b + c * c + d * d);
            b *= s;
            c *= s;
            d *= s;
            a = 0.0;
        } else {
            a = std::sqrt(a);
        }
        const double qfac = h.pixdim[0] < 0 ? -1.0 : 1.0;
        const double R[3][3] = {{a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)},
                                {2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b)},
                                {2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - c * c - b * b}};
        for (int r = 0; r < 3; ++r)
            for (int col = 0; col < 3; ++col) qdir[r][col] = R[r][col] * (col == 2 ? qfac : 1.0);
    }
    const Vec3d qoff{h.qoffset_x, h.qoffset_y, h.qoffset_z};
    const Vec3d soff{srow[0][3], srow[1][3], srow[2][3]};
    bool similar = sformUsable && h.qform_code > 0;
    for (int r = 0; r < 3 && similar; ++r) {
        if (std::fabs(soff[r] - qoff[r]) > 1e-4) similar = false;
        for (int c = 0; c < 3; ++c)
            if (std::fabs(sdir[r][c] - qdir[r][c]) > 1e-4) similar = false;
    }
    const bool useSform = sformUsable && (h.qform_code <= 0 || h.sform_code == 1 || similar);
    if (!useSform && h.qform_code <= 0)
        throw InputError(path + ": the NIfTI-2 sform has shear or a scaling that pixdim does not match, and there "
                                "is no qform; world positions cannot be given by spacing and directions");
    const Mat3d& dir = useSform ? sdir : qdir;
    const Vec3d& off = useSform ? soff : qoff;
    for (int r = 0; r < 3; ++r) {
        g.originMm[r] = lps(r) * off[r] * unit;
        for (int c = 0; c < 3; ++c) g.direction[r][c] = lps(r) * dir[r][c];
    }
    return g;
}

/// A NIfTI-2 file (.nii, .nii.gz, or a .hdr of a .hdr/.img pair), streamed by slab.
class Nifti2Source final : public ImageSource {
public:
    explicit Nifti2Source(const std::string& path)
    {
        mName = path;
        const Nifti2Header header = readNifti2Header(path);
        const nifti_2_header& h = header.h;
        mSwapped = header.swapped;
        const int64_t nd = h.dim[0];
        if (nd < 1 || nd > 7) throw InputError(path + ": NIfTI-2 dim[0] is " + std::to_string(nd) + "; expected 1 to 7");
        std::string sizeList;
        for (int64_t d = 1; d <= nd; ++d) {
            if (h.dim[d] < 1 || h.dim[d] > (int64_t(1) << 31))
                throw InputError(path + ": NIfTI-2 dim[" + std::to_string(d) + "] is " + std::to_string(h.dim[d]) +
                                 "; expected 1 to 2^31");
            sizeList += (sizeList.empty() ? "" : " x ") + std::to_string(h.dim[d]);
        }
        if (nd < 3 || h.dim[1] < 2 || h.dim[2] < 2 || h.dim[3] < 2)
            throw InputError(path + ": image is 2D (" + sizeList + "); a 3D volume is needed");
        for (int64_t d = 4; d <= nd; ++d)
            if (h.dim[d] > 1)
                throw InputError(path + ": image is " + std::to_string(nd) + "D (" + sizeList +
                                 "), e.g. a time series; a single 3D volume is needed");
        // Dims up to 2^31 each: their product can overflow int64 (found by fuzzing). 2^56
        // bytes is far beyond any file, and the data size is checked against the file below.
        const long double totalBytes =
            static_cast<long double>(h.dim[1]) * h.dim[2] * h.dim[3] * std::max<long double>(1, h.bitpix / 8);
        if (totalBytes > static_cast<long double>(int64_t(1) << 56))
            throw InputError(path + ": NIfTI-2 header describes " + sizeList + " voxels, more than any file holds");
        int bytes = 0;
        mType = niftiComponentType(h.datatype, bytes);
        if (bytes == 0)
            throw InputError(path + ": voxel type " + nifti2TypeName(h.datatype) +
                             " is not supported (integers up to 64 bits, float and double are)");
        mComponentBytes = static_cast<std::size_t>(bytes);
        if (h.bitpix != 8 * bytes)
            throw InputError(path + ": NIfTI-2 bitpix " + std::to_string(h.bitpix) + " does not match datatype " +
                             std::to_string(h.datatype) + " (" + std::to_string(8 * bytes) + " bits)");
        mGeometry = nifti2Geometry(h, path);
        validateGeometry(mGeometry, path);
        if (!std::isfinite(h.scl_slope) || !std::isfinite(h.scl_inter))
            throw InputError(path + ": NIfTI-2 scl_slope or scl_inter is not finite");
        if (h.scl_slope != 0 && !(h.scl_slope == 1 && h.scl_inter == 0)) {
            mSlope = h.scl_slope;
            mInter = h.scl_inter;
            mScaled = true;
        }

        // Where the voxels are.
        const std::string lower = lowerCase(path);
        const bool pair = std::memcmp(h.magic, "ni2\0", 4) == 0;
        fs::path data = path;
        bool compressed = endsWith(lower, ".gz");
        if (pair) {
            if (!endsWith(lower, ".hdr")) throw InputError(path + ": a NIfTI-2 'ni2' header belongs in a .hdr file");
            data = fs::path(path).replace_extension(".img");
            if (!fs::exists(data) && fs::exists(data.string() + ".gz")) data = data.string() + ".gz";
            compressed = endsWith(lowerCase(data.string()), ".gz");
        }
        if (h.vox_offset < (pair ? 0 : 540))
            throw InputError(path + ": NIfTI-2 vox_offset " + std::to_string(h.vox_offset) + " lies inside the header");
        mOffset = static_cast<uint64_t>(h.vox_offset);
        const uint64_t need = static_cast<uint64_t>(mGeometry.voxelCount()) * mComponentBytes;
        std::string how = "streamed by slab";
        if (compressed) {
            if (!fs::exists(data)) throw InputError(path + ": its voxel data file " + data.string() + " does not exist");
            how = "inflated by ISA-L while streamed by slab";
        } else {
            if (!fs::exists(data)) throw InputError(path + ": its voxel data file " + data.string() + " does not exist");
            const uint64_t have = fileBytes(data.string());
            if (have < mOffset + need) {
                std::ostringstream os;
                os << path << ": header/data size mismatch: the header describes " << sizeText(mGeometry.size) << " "
                   << 8 * bytes << "-bit voxels (" << need << " bytes after " << mOffset << ") but the file holds "
                   << have << " bytes (truncated?)";
                throw InputError(os.str());
            }
        }
        RawLayout layout;
        layout.dataPath = data.string();
        layout.compressed = compressed;
        layout.offset = mOffset;
        layout.type = mType;
        layout.componentBytes = mComponentBytes;
        layout.swapped = mSwapped;
        layout.scaled = mScaled;
        layout.slope = mSlope;
        layout.inter = mInter;
        layout.size = mGeometry.size;
        mVoxels = std::make_unique<RawVoxels>(path, layout);
        mRegular = true;
        for (int64_t k = 0; k < mGeometry.size[2]; ++k)
            mSliceOriginsMm.push_back(mGeometry.worldFromIndex({0, 0, double(k)}));
        mDescription = "NIfTI-2 (header by flyover with nifticlib's nifti2.h; ITK 5.2 reads NIfTI-1 only), " + how;
    }

    void addWarning(const std::string& text) { mWarnings.push_back(text); }

    void readSlices(int64_t k0, int64_t k1, float* out) override { mVoxels->readSlices(k0, k1, out); }

private:
    bool mSwapped = false;
    IOComponentEnum mType = IOComponentEnum::UNKNOWNCOMPONENTTYPE;
    std::size_t mComponentBytes = 0;
    uint64_t mOffset = 0;
    bool mScaled = false;
    double mSlope = 1, mInter = 0;
    std::unique_ptr<RawVoxels> mVoxels;
};

} // namespace

std::unique_ptr<ImageSource> openNifti2(const std::string& path, const std::string& warning)
{
    auto source = std::make_unique<Nifti2Source>(path);
    if (!warning.empty()) source->addWarning(warning);
    return source;
}

} // namespace flyover::imageio
