/// @file slab_writer.cpp
/// @brief Streaming uint16 volume writer (see slab_writer.h).
#include "volume/slab_writer.h"

#include "volume/error.h"
#include "volume/io/io_util.h"

#include <nifti/nifti1.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <sstream>

namespace fs = std::filesystem;

namespace flyover {

static_assert(sizeof(nifti_1_header) == 348, "NIfTI-1 header must be 348 bytes");

/// The slab writer's output formats (outside the anonymous namespace: SlabWriter::Impl holds one).
enum class SlabFormat { Nii, NiiGz, Nrrd };

namespace {

using imageio::endsWith;

bool hostIsLittleEndian()
{
    const uint16_t one = 1;
    unsigned char b;
    std::memcpy(&b, &one, 1);
    return b == 1;
}

nifti_1_header niftiHeader(const ImageGeometry& g)
{
    nifti_1_header h;
    std::memset(&h, 0, sizeof h);
    h.sizeof_hdr = 348;
    h.dim[0] = 3;
    for (int a = 0; a < 3; ++a) h.dim[a + 1] = static_cast<short>(g.size[a]);
    for (int a = 4; a < 8; ++a) h.dim[a] = 1;
    h.datatype = NIFTI_TYPE_UINT16;
    h.bitpix = 16;
    h.pixdim[0] = 1.0f;  // qfac
    for (int a = 0; a < 3; ++a) h.pixdim[a + 1] = static_cast<float>(g.spacingMm[a]);
    h.vox_offset = 352.0f;
    h.scl_slope = 1.0f;
    h.scl_inter = 0.0f;
    h.xyzt_units = NIFTI_UNITS_MM;
    // NIfTI's world is RAS: x_RAS = -x_LPS, y_RAS = -y_LPS. With identity LPS direction cosines
    // the RAS rotation is diag(-1, -1, 1): a proper rotation (180 deg about z), quaternion
    // (a, b, c, d) = (0, 0, 0, 1).
    h.qform_code = NIFTI_XFORM_SCANNER_ANAT;
    h.sform_code = NIFTI_XFORM_SCANNER_ANAT;
    h.quatern_b = 0.0f;
    h.quatern_c = 0.0f;
    h.quatern_d = 1.0f;
    h.qoffset_x = static_cast<float>(-g.originMm.x);
    h.qoffset_y = static_cast<float>(-g.originMm.y);
    h.qoffset_z = static_cast<float>(g.originMm.z);
    h.srow_x[0] = static_cast<float>(-g.spacingMm.x);
    h.srow_x[3] = static_cast<float>(-g.originMm.x);
    h.srow_y[1] = static_cast<float>(-g.spacingMm.y);
    h.srow_y[3] = static_cast<float>(-g.originMm.y);
    h.srow_z[2] = static_cast<float>(g.spacingMm.z);
    h.srow_z[3] = static_cast<float>(g.originMm.z);
    std::strncpy(h.descrip, "flyover part phantom", sizeof h.descrip - 1);
    std::memcpy(h.magic, "n+1\0", 4);
    return h;
}

std::string nrrdHeader(const ImageGeometry& g)
{
    std::ostringstream o;
    o.precision(17);
    o << "NRRD0004\n"
      << "# written by flyover\n"
      << "type: uint16\n"
      << "dimension: 3\n"
      << "space: left-posterior-superior\n"
      << "sizes: " << g.size[0] << " " << g.size[1] << " " << g.size[2] << "\n"
      << "space directions: (" << g.spacingMm.x << ",0,0) (0," << g.spacingMm.y << ",0) (0,0,"
      << g.spacingMm.z << ")\n"
      << "kinds: domain domain domain\n"
      << "endian: little\n"
      << "encoding: raw\n"
      << "space origin: (" << g.originMm.x << "," << g.originMm.y << "," << g.originMm.z << ")\n\n";
    return o.str();
}

} // namespace

struct SlabWriter::Impl {
    std::string path;
    fs::path tmp;
    ImageGeometry geometry;
    SlabFormat format = SlabFormat::Nii;
    std::FILE* file = nullptr;
    gzFile gz = nullptr;
    int64_t slicesWritten = 0;
    bool finished = false;

    void write(const void* data, std::size_t bytes)
    {
        if (gz) {
            // gzwrite takes an unsigned count: write in chunks well below 4 GiB.
            const char* p = static_cast<const char*>(data);
            while (bytes > 0) {
                const unsigned n = static_cast<unsigned>(std::min<std::size_t>(bytes, 1u << 30));
                if (::gzwrite(gz, p, n) != static_cast<int>(n)) {
                    int err = 0;
                    const char* msg = ::gzerror(gz, &err);
                    throw InputError(path + ": cannot write (" + std::string(msg ? msg : "zlib error") + ")");
                }
                p += n;
                bytes -= n;
            }
        } else if (std::fwrite(data, 1, bytes, file) != bytes) {
            throw InputError(path + ": cannot write (" + std::strerror(errno) + ")");
        }
    }

    void close()
    {
        if (gz) {
            const int rc = ::gzclose(gz);
            gz = nullptr;
            if (rc != Z_OK) throw InputError(path + ": cannot finish the gzip stream");
        }
        if (file) {
            const int rc = std::fclose(file);
            file = nullptr;
            if (rc != 0) throw InputError(path + ": cannot close (" + std::string(std::strerror(errno)) + ")");
        }
    }
};

SlabWriter::SlabWriter(const std::string& path, const ImageGeometry& geometry) : mImpl(new Impl)
{
    Impl& m = *mImpl;
    m.path = path;
    m.geometry = geometry;
    if (endsWith(path, ".nii.gz")) m.format = SlabFormat::NiiGz;
    else if (endsWith(path, ".nii")) m.format = SlabFormat::Nii;
    else if (endsWith(path, ".nrrd")) m.format = SlabFormat::Nrrd;
    else throw ParameterError(path + ": unknown volume format (expected .nii, .nii.gz or .nrrd)");
    if (geometry.direction != identityMat3())
        throw ParameterError(path + ": the slab writer writes axis-aligned (identity direction) volumes only");
    for (int a = 0; a < 3; ++a) {
        if (!(geometry.size[a] > 0)) throw ParameterError(path + ": empty volume size");
        if (m.format != SlabFormat::Nrrd && geometry.size[a] > 32767)
            throw ParameterError(path + ": NIfTI-1 holds at most 32767 voxels along an axis");
        if (!(geometry.spacingMm[a] > 0) || !std::isfinite(geometry.spacingMm[a]))
            throw ParameterError(path + ": voxel size must be > 0 and finite");
    }
    if (!hostIsLittleEndian()) throw ParameterError(path + ": the slab writer needs a little-endian host");

    const fs::path target(path);
    m.tmp = target.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string());
    if (m.format == SlabFormat::NiiGz) {
        m.gz = ::gzopen(m.tmp.c_str(), "wb1");
        if (!m.gz) throw InputError(path + ": cannot create (" + std::string(std::strerror(errno)) + ")");
    } else {
        m.file = std::fopen(m.tmp.c_str(), "wb");
        if (!m.file) throw InputError(path + ": cannot create (" + std::string(std::strerror(errno)) + ")");
    }
    if (m.format == SlabFormat::Nrrd) {
        const std::string h = nrrdHeader(geometry);
        m.write(h.data(), h.size());
    } else {
        const nifti_1_header h = niftiHeader(geometry);
        m.write(&h, sizeof h);
        const char extension[4] = {0, 0, 0, 0};
        m.write(extension, 4);
    }
}

SlabWriter::~SlabWriter()
{
    if (!mImpl) return;
    if (!mImpl->finished) {
        try {
            mImpl->close();
        } catch (...) {
        }
        std::error_code ec;
        fs::remove(mImpl->tmp, ec);
    }
}

void SlabWriter::writeSlice(const uint16_t* voxels)
{
    Impl& m = *mImpl;
    if (m.finished || m.slicesWritten >= m.geometry.size[2])
        throw std::logic_error(m.path + ": more slices written than the volume has");
    m.write(voxels, sizeof(uint16_t) * static_cast<std::size_t>(m.geometry.size[0] * m.geometry.size[1]));
    ++m.slicesWritten;
}

void SlabWriter::finish()
{
    Impl& m = *mImpl;
    if (m.slicesWritten != m.geometry.size[2])
        throw std::logic_error(m.path + ": " + std::to_string(m.slicesWritten) + " of " +
                               std::to_string(m.geometry.size[2]) + " slices written");
    if (m.file && std::fflush(m.file) == 0) ::fsync(::fileno(m.file));
    m.close();
    std::error_code ec;
    fs::rename(m.tmp, m.path, ec);
    if (ec) {
        fs::remove(m.tmp, ec);
        throw InputError(m.path + ": cannot rename the finished file into place (" + ec.message() + ")");
    }
    m.finished = true;
}

std::size_t SlabWriter::bufferedBytes() const
{
    return sizeof(uint16_t) * static_cast<std::size_t>(mImpl->geometry.size[0] * mImpl->geometry.size[1]);
}

} // namespace flyover
