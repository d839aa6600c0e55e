// Scan reading and image writing through ITK's IO: the one place in flyover that includes ITK.
// IO factories are registered explicitly (instead of ITK_USE_FILE's generated manager), so
// only the formats listed here exist, and ITK's global definitions stay out of other code.
//
// ITK's readers are trusted for parsing and geometry, not for telling us when data is
// missing: measured on ITK 5.2, a truncated .nii/.nii.gz reads "successfully" with the tail
// zero-filled, a short MetaImage only prints to std::cerr, and a DICOM file with cut pixel
// data only triggers a GDCM warning. Hence the explicit size checks, the decompression of
// gzipped NIfTI by zlib (which reports truncation), the sentinel re-read for MetaImage, and
// the capture of the libraries' console chatter (which also keeps the CLI's promise of one
// line per error).

#include "volume/image_io.h"

#include "volume/error.h"

#include <itkGDCMImageIO.h>
#include <itkGDCMImageIOFactory.h>
#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkMetaDataObject.h>
#include <itkMetaImageIO.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIO.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIO.h>
#include <itkNrrdImageIOFactory.h>

#include <nifti/nifti2.h>  // the NIfTI-2 header struct only (see Nifti2Source)

#include <tbb/parallel_for.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <new>
#include <sstream>
#include <streambuf>
#include <thread>

#include <csignal>
#include <fcntl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;

namespace flyover {

namespace {

using itk::IOComponentEnum;

void registerImageIO()
{
    static std::once_flag once;
    std::call_once(once, [] {
        itk::NiftiImageIOFactory::RegisterOneFactory();
        itk::NrrdImageIOFactory::RegisterOneFactory();
        itk::MetaImageIOFactory::RegisterOneFactory();
        itk::GDCMImageIOFactory::RegisterOneFactory();
        // Our own checks report what matters; ITK's warnings would only add console lines.
        itk::Object::GlobalWarningDisplayOff();
    });
}

// ------------------------------------------------------------------ console chatter capture

/// A string sink safe to write from several threads (DICOM files are decoded in parallel).
class LockedStringBuf : public std::streambuf {
public:
    std::string take()
    {
        std::lock_guard<std::mutex> lock(mMutex);
        std::string t;
        t.swap(mText);
        return t;
    }

protected:
    int_type overflow(int_type c) override
    {
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            std::lock_guard<std::mutex> lock(mMutex);
            mText.push_back(traits_type::to_char_type(c));
        }
        return traits_type::not_eof(c);
    }
    std::streamsize xsputn(const char* s, std::streamsize n) override
    {
        std::lock_guard<std::mutex> lock(mMutex);
        mText.append(s, static_cast<std::size_t>(n));
        return n;
    }

private:
    std::mutex mMutex;
    std::string mText;
};

/// While alive, std::cout and std::cerr (where ITK, GDCM's trace and MetaIO write their
/// warnings) go to a buffer instead of the console.
class CapturedOutput {
public:
    CapturedOutput() : mOldErr(std::cerr.rdbuf(&mBuf)), mOldOut(std::cout.rdbuf(&mBuf)) {}
    ~CapturedOutput()
    {
        std::cerr.rdbuf(mOldErr);
        std::cout.rdbuf(mOldOut);
    }
    CapturedOutput(const CapturedOutput&) = delete;
    CapturedOutput& operator=(const CapturedOutput&) = delete;
    std::string take() { return mBuf.take(); }

private:
    LockedStringBuf mBuf;
    std::streambuf* mOldErr;
    std::streambuf* mOldOut;
};

// ------------------------------------------------------------------------------ messages

std::string trim(const std::string& s)
{
    const auto a = s.find_first_not_of(" \t\r\n");
    if (a == std::string::npos) return "";
    const auto b = s.find_last_not_of(" \t\r\n");
    return s.substr(a, b - a + 1);
}

/// One line out of an ITK exception: NRRD's error stack ends with its deepest cause; other
/// readers put theirs first. The "ITK ERROR: Class(0x...): " prefix is dropped.
std::string itkReason(const itk::ExceptionObject& e)
{
    std::istringstream in(e.GetDescription());
    std::string line, first, lastNrrd;
    while (std::getline(in, line)) {
        line = trim(line);
        if (line.empty()) continue;
        if (line.rfind("[nrrd]", 0) == 0) lastNrrd = trim(line.substr(6));
        else if (first.empty()) first = line;
    }
    std::string r = !lastNrrd.empty() ? lastNrrd : first;
    if (r.rfind("ITK ERROR:", 0) == 0 || r.rfind("itk::ERROR:", 0) == 0) {
        const auto p = r.find("): ");
        if (p != std::string::npos) r = r.substr(p + 3);
    }
    if (r.empty()) r = "unknown ITK error";
    return r;
}

std::string sizeText(const std::array<int64_t, 3>& s)
{
    return std::to_string(s[0]) + " x " + std::to_string(s[1]) + " x " + std::to_string(s[2]);
}

std::string bytesText(uint64_t b)
{
    std::ostringstream os;
    os.precision(3);
    if (b >= (1ull << 30)) os << double(b) / double(1ull << 30) << " GiB";
    else if (b >= (1ull << 20)) os << double(b) / double(1ull << 20) << " MiB";
    else os << b << " bytes";
    return os.str();
}

std::string lowerCase(std::string s)
{
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return s;
}

bool endsWith(const std::string& s, const std::string& suffix)
{
    return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

/// The format a file name promises, for messages when no reader accepts the file.
std::string formatFromName(const std::string& path)
{
    const std::string n = lowerCase(fs::path(path).filename().string());
    for (const char* e : {".nii", ".nii.gz", ".hdr", ".img", ".img.gz"})
        if (endsWith(n, e)) return "NIfTI";
    if (endsWith(n, ".nrrd") || endsWith(n, ".nhdr")) return "NRRD";
    if (endsWith(n, ".mha") || endsWith(n, ".mhd")) return "MetaImage";
    if (endsWith(n, ".dcm") || endsWith(n, ".dicom") || endsWith(n, ".ima")) return "DICOM";
    return "";
}

std::string formatOfIo(const itk::ImageIOBase& io)
{
    const std::string c = io.GetNameOfClass();
    if (c == "NiftiImageIO") return "NIfTI";
    if (c == "NrrdImageIO") return "NRRD";
    if (c == "MetaImageIO") return "MetaImage";
    if (c == "GDCMImageIO") return "DICOM";
    return c;
}

// --------------------------------------------------------------------- pixel conversion

std::size_t componentBytes(IOComponentEnum t)
{
    switch (t) {
    case IOComponentEnum::UCHAR: case IOComponentEnum::CHAR: return 1;
    case IOComponentEnum::USHORT: case IOComponentEnum::SHORT: return 2;
    case IOComponentEnum::UINT: case IOComponentEnum::INT: case IOComponentEnum::FLOAT: return 4;
    case IOComponentEnum::ULONG: case IOComponentEnum::LONG: return sizeof(long);
    case IOComponentEnum::ULONGLONG: case IOComponentEnum::LONGLONG: case IOComponentEnum::DOUBLE: return 8;
    default: return 0;  // unknown or long double: not supported
    }
}

template <typename T>
void convertSpan(const void* src, std::size_t n, float* dst)
{
    const T* s = static_cast<const T*>(src);
    for (std::size_t i = 0; i < n; ++i) dst[i] = static_cast<float>(s[i]);
}

/// Native voxels -> float. Returns the index of the first non-finite value, or n.
std::size_t toFloat(const void* src, IOComponentEnum t, std::size_t n, float* dst)
{
    switch (t) {
    case IOComponentEnum::UCHAR: convertSpan<uint8_t>(src, n, dst); return n;
    case IOComponentEnum::CHAR: convertSpan<int8_t>(src, n, dst); return n;
    case IOComponentEnum::USHORT: convertSpan<uint16_t>(src, n, dst); return n;
    case IOComponentEnum::SHORT: convertSpan<int16_t>(src, n, dst); return n;
    case IOComponentEnum::UINT: convertSpan<uint32_t>(src, n, dst); return n;
    case IOComponentEnum::INT: convertSpan<int32_t>(src, n, dst); return n;
    case IOComponentEnum::ULONG: convertSpan<unsigned long>(src, n, dst); return n;
    case IOComponentEnum::LONG: convertSpan<long>(src, n, dst); return n;
    case IOComponentEnum::ULONGLONG: convertSpan<unsigned long long>(src, n, dst); return n;
    case IOComponentEnum::LONGLONG: convertSpan<long long>(src, n, dst); return n;
    case IOComponentEnum::FLOAT: convertSpan<float>(src, n, dst); break;
    case IOComponentEnum::DOUBLE: convertSpan<double>(src, n, dst); break;
    default: throw std::logic_error("toFloat: unsupported component type");
    }
    // Floating-point input: NaN, Inf, and doubles beyond float range (now Inf) are refused.
    return static_cast<std::size_t>(std::find_if(dst, dst + n, [](float v) { return !std::isfinite(v); }) - dst);
}

[[noreturn]] void throwNonFinite(const std::string& name, const std::array<int64_t, 3>& size, int64_t k0,
                                 std::size_t n, float value)
{
    const int64_t sliceSize = size[0] * size[1];
    const int64_t i = static_cast<int64_t>(n) % size[0];
    const int64_t j = (static_cast<int64_t>(n) % sliceSize) / size[0];
    const int64_t k = k0 + static_cast<int64_t>(n) / sliceSize;
    std::ostringstream os;
    os << name << ": voxel (" << i << "," << j << "," << k << ") is " << value
       << "; NaN and Inf voxels are not allowed";
    throw InputError(os.str());
}

// ------------------------------------------------------------------------------ geometry

void validateGeometry(const ImageGeometry& g, const std::string& path)
{
    static const char* AXIS[3] = {"i (x)", "j (y)", "k (z)"};
    for (int c = 0; c < 3; ++c) {
        if (g.size[c] < 1) throw InputError(path + ": image has an empty dimension");
        if (!(g.spacingMm[c] > 0) || !std::isfinite(g.spacingMm[c])) {
            std::ostringstream os;
            os << path << ": voxel spacing along " << AXIS[c] << " is " << g.spacingMm[c]
               << " mm; expected a positive finite value";
            throw InputError(os.str());
        }
        if (!std::isfinite(g.originMm[c])) throw InputError(path + ": image origin is not finite");
    }
    // Direction cosines must be orthonormal, or world positions are meaningless.
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            double d = 0;
            for (int r = 0; r < 3; ++r) d += g.direction[r][a] * g.direction[r][b];
            if (!(std::fabs(d - (a == b ? 1.0 : 0.0)) < 1e-3))
                throw InputError(path + ": direction cosines are not orthonormal");
        }
}

/// Checks dimension, pixel type and geometry of a header ITK has read.
ImageGeometry checkHeader(itk::ImageIOBase& io, const std::string& path)
{
    const unsigned dims = io.GetNumberOfDimensions();
    std::vector<uint64_t> sizes;
    for (unsigned d = 0; d < dims; ++d) sizes.push_back(io.GetDimensions(d));
    std::string sizeList;
    for (auto s : sizes) sizeList += (sizeList.empty() ? "" : " x ") + std::to_string(s);
    if (dims < 3 || sizes[0] < 2 || sizes[1] < 2 || sizes[2] < 2)
        throw InputError(path + ": image is 2D (" + sizeList + "); a 3D volume is needed");
    for (unsigned d = 3; d < dims; ++d)
        if (sizes[d] > 1)
            throw InputError(path + ": image is " + std::to_string(dims) + "D (" + sizeList +
                             "), e.g. a time series; a single 3D volume is needed");
    if (io.GetPixelType() != itk::IOPixelEnum::SCALAR || io.GetNumberOfComponents() != 1)
        throw InputError(path + ": pixel type is " + itk::ImageIOBase::GetPixelTypeAsString(io.GetPixelType()) +
                         " with " + std::to_string(io.GetNumberOfComponents()) +
                         " components per voxel; a scalar (grey-value) image is needed");
    if (componentBytes(io.GetComponentType()) == 0)
        throw InputError(path + ": voxel type " + itk::ImageIOBase::GetComponentTypeAsString(io.GetComponentType()) +
                         " is not supported (integers up to 64 bits, float and double are)");
    // Sizes are unsigned 64-bit: a hostile header can make their product wrap around, and the
    // data size check with it. 2^56 bytes is far beyond any file.
    long double totalBytes = static_cast<long double>(componentBytes(io.GetComponentType()));
    for (auto sz : sizes) totalBytes *= static_cast<long double>(sz);
    if (totalBytes > static_cast<long double>(int64_t(1) << 56))
        throw InputError(path + ": header describes " + sizeList + " voxels, more than any file holds");
    ImageGeometry g;
    for (int c = 0; c < 3; ++c) {
        g.size[c] = static_cast<int64_t>(sizes[c]);
        g.spacingMm[c] = io.GetSpacing(c);
        g.originMm[c] = io.GetOrigin(c);
        const auto dir = io.GetDirection(c);
        for (int r = 0; r < 3; ++r) g.direction[r][c] = r < int(dir.size()) ? dir[r] : 0.0;
    }
    validateGeometry(g, path);
    return g;
}

// ---------------------------------------------------------------- data size, temp copies

std::string metaString(const itk::ImageIOBase& io, const std::string& key)
{
    std::string v;
    itk::ExposeMetaData<std::string>(io.GetMetaDataDictionary(), key, v);
    return trim(v);
}

uint64_t fileBytes(const fs::path& p)
{
    std::error_code ec;
    const auto n = fs::file_size(p, ec);
    return ec ? 0 : static_cast<uint64_t>(n);
}

/// Where a header's voxels live on disk (as far as the header tells).
struct DataFile {
    fs::path path;            ///< empty: unknown (several files, or a reader we cannot ask)
    uint64_t offset = 0;      ///< bytes before the voxels
    uint64_t bytes = 0;       ///< voxel bytes as stored
    bool compressed = false;
};

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

/// A private temporary folder, removed with everything in it.
class TempDir {
public:
    TempDir()
    {
        std::string pattern = (fs::temp_directory_path() / "flyover-ingest-XXXXXX").string();
        if (!::mkdtemp(pattern.data()))
            throw InputError("cannot create a temporary folder in " + fs::temp_directory_path().string() +
                             ": " + std::strerror(errno) + " (set TMPDIR)");
        mPath = pattern;
    }
    ~TempDir()
    {
        std::error_code ec;
        fs::remove_all(mPath, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    const fs::path& path() const { return mPath; }

private:
    fs::path mPath;
};

/// zlib-decompresses `from` into `to`; refuses truncated or corrupt streams and output
/// shorter than `needBytes`.
void gunzipFile(const fs::path& from, const fs::path& to, uint64_t needBytes, const std::string& name)
{
    gzFile in = ::gzopen(from.c_str(), "rb");
    if (!in) throw InputError(name + ": cannot open " + from.string() + ": " + std::strerror(errno));
    ::gzbuffer(in, 1 << 20);
    std::FILE* out = std::fopen(to.c_str(), "wb");
    if (!out) {
        ::gzclose(in);
        throw InputError(name + ": cannot create the temporary file " + to.string() + ": " +
                         std::strerror(errno) + " (set TMPDIR)");
    }
    std::vector<char> buf(4 << 20);
    uint64_t total = 0;
    std::string problem;
    for (;;) {
        const int n = ::gzread(in, buf.data(), static_cast<unsigned>(buf.size()));
        if (n < 0) break;
        if (n == 0) break;
        if (std::fwrite(buf.data(), 1, static_cast<std::size_t>(n), out) != static_cast<std::size_t>(n)) {
            problem = "cannot decompress into " + fs::path(to).parent_path().string() + ": " + std::strerror(errno) +
                      " (it needs " + bytesText(needBytes) + "; set TMPDIR to a folder with room)";
            break;
        }
        total += static_cast<uint64_t>(n);
    }
    int err = Z_OK;
    const char* zmsg = ::gzerror(in, &err);
    if (problem.empty() && err != Z_OK && err != Z_STREAM_END) {
        std::string why = zmsg ? zmsg : "zlib error";
        const std::string prefix = from.string() + ": ";  // zlib names the file itself
        if (why.rfind(prefix, 0) == 0) why = why.substr(prefix.size());
        problem = "gzip data is truncated or corrupt after " + std::to_string(total) + " decompressed bytes (" + why + ")";
    }
    ::gzclose(in);
    if (std::fclose(out) != 0 && problem.empty())
        problem = "cannot write the temporary file " + to.string() + ": " + std::strerror(errno);
    if (!problem.empty()) throw InputError(name + ": " + problem);
    if (total < needBytes)
        throw InputError(name + ": header/data size mismatch: the header needs " + std::to_string(needBytes) +
                         " bytes, the decompressed file holds " + std::to_string(total) + " (truncated?)");
}

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

// ---------------------------------------------------------------------------- file sources

/// A NIfTI, NRRD, MetaImage or single DICOM file through one ITK ImageIO.
class FileSource final : public ImageSource {
public:
    FileSource(const std::string& path, itk::ImageIOBase::Pointer io, const ImageGeometry& g, bool streamed,
               std::unique_ptr<TempDir> temp, const std::string& description)
        : mIo(std::move(io)), mTemp(std::move(temp)), mStreamed(streamed),
          mType(mIo->GetComponentType()), mComponentBytes(mIo->GetComponentSize())
    {
        mName = path;
        mGeometry = g;
        mRegular = true;
        for (int64_t k = 0; k < g.size[2]; ++k) mSliceOriginsMm.push_back(g.worldFromIndex({0, 0, double(k)}));
        mDescription = description;
        mSentinelCheck = formatOfIo(*mIo) == "MetaImage";
        if (!mStreamed) mHeldBytes = static_cast<int64_t>(sliceBytes() * static_cast<std::size_t>(g.size[2]));
    }

    void addWarning(const std::string& text) { mWarnings.push_back(text); }

    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const auto& s = mGeometry.size;
        if (!(0 <= k0 && k0 < k1 && k1 <= s[2])) throw std::out_of_range("readSlices: slice range");
        const std::size_t voxelsPerSlice = static_cast<std::size_t>(s[0] * s[1]);
        const std::size_t n = voxelsPerSlice * static_cast<std::size_t>(k1 - k0);
        const char* native = nullptr;
        if (mStreamed) {
            mSlab.resize(sliceBytes() * static_cast<std::size_t>(k1 - k0));
            readRegion(k0, k1, mSlab.data(), mSlab.size());
            native = mSlab.data();
        } else {
            if (mWhole.empty()) {
                try {
                    mWhole.resize(sliceBytes() * static_cast<std::size_t>(s[2]));
                } catch (const std::bad_alloc&) {
                    throw InputError(mName + ": cannot allocate " + bytesText(sliceBytes() * std::size_t(s[2])) +
                                     " for the " + sizeText(s) + " voxels its header describes");
                }
                readRegion(0, s[2], mWhole.data(), mWhole.size());
            }
            native = mWhole.data() + sliceBytes() * static_cast<std::size_t>(k0);
        }
        const std::size_t bad = toFloat(native, mType, n, out);
        if (bad < n) throwNonFinite(mName, s, k0, bad, out[bad]);
    }

private:
    std::size_t sliceBytes() const
    {
        return static_cast<std::size_t>(mGeometry.size[0] * mGeometry.size[1]) * mComponentBytes;
    }

    void readRegion(int64_t k0, int64_t k1, char* buffer, std::size_t bytes)
    {
        const unsigned dims = mIo->GetNumberOfDimensions();
        itk::ImageIORegion region(dims);
        for (unsigned d = 0; d < dims; ++d) {
            region.SetIndex(d, 0);
            region.SetSize(d, d < 2 ? static_cast<itk::SizeValueType>(mGeometry.size[d]) : 1);
        }
        region.SetIndex(2, k0);
        region.SetSize(2, static_cast<itk::SizeValueType>(k1 - k0));
        // MetaIO leaves the unread tail of a short file untouched and only prints a message:
        // fill with a pattern, and if the tail still holds it, read again with another pattern
        // (real data cannot match both).
        const unsigned char patterns[2] = {0xA5, 0x5A};
        const std::size_t tail = std::min<std::size_t>(bytes, 16);
        for (int attempt = 0; attempt < (mSentinelCheck ? 2 : 1); ++attempt) {
            if (mSentinelCheck) std::memset(buffer, patterns[attempt], bytes);
            std::string chatter;
            try {
                CapturedOutput capture;
                mIo->SetIORegion(region);
                mIo->Read(buffer);
                chatter = capture.take();
            } catch (const itk::ExceptionObject& e) {
                throw InputError(mName + ": cannot read the voxel data: " + itkReason(e));
            }
            if (chatter.find("not read completely") != std::string::npos)
                throw InputError(mName + ": the voxel data ends early (truncated file, or header/data size mismatch)");
            if (!mSentinelCheck) return;
            const bool untouched = std::all_of(buffer + bytes - tail, buffer + bytes, [&](char c) {
                return static_cast<unsigned char>(c) == patterns[attempt];
            });
            if (!untouched) return;
        }
        throw InputError(mName + ": the voxel data ends early (truncated file, or header/data size mismatch)");
    }

    itk::ImageIOBase::Pointer mIo;
    std::unique_ptr<TempDir> mTemp;  // the decompressed copy that mIo reads, if any
    bool mStreamed;
    bool mSentinelCheck = false;
    IOComponentEnum mType;
    std::size_t mComponentBytes;
    std::vector<char> mSlab;   // streamed: the native slab buffer
    std::vector<char> mWhole;  // buffered: the whole image in its native type
};

// ---------------------------------------------------------------------------------- NIfTI-2

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
// (slope 0 means none), streamed by slab (gzip first inflated to a temporary file).

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

IOComponentEnum nifti2ComponentType(int datatype, int& bytes)
{
    switch (datatype) {
    case 2: bytes = 1; return IOComponentEnum::UCHAR;       // DT_UINT8
    case 256: bytes = 1; return IOComponentEnum::CHAR;      // DT_INT8
    case 4: bytes = 2; return IOComponentEnum::SHORT;       // DT_INT16
    case 512: bytes = 2; return IOComponentEnum::USHORT;    // DT_UINT16
    case 8: bytes = 4; return IOComponentEnum::INT;         // DT_INT32
    case 768: bytes = 4; return IOComponentEnum::UINT;      // DT_UINT32
    case 16: bytes = 4; return IOComponentEnum::FLOAT;      // DT_FLOAT32
    case 1024: bytes = 8; return IOComponentEnum::LONGLONG; // DT_INT64
    case 1280: bytes = 8; return IOComponentEnum::ULONGLONG;// DT_UINT64
    case 64: bytes = 8; return IOComponentEnum::DOUBLE;     // DT_FLOAT64
    default: bytes = 0; return IOComponentEnum::UNKNOWNCOMPONENTTYPE;
    }
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
        mType = nifti2ComponentType(h.datatype, bytes);
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
            mTemp = std::make_unique<TempDir>();
            const fs::path copy = mTemp->path() / "voxels.raw";
            gunzipFile(data, copy, mOffset + need, path);
            data = copy;
            how = "gunzipped by zlib to a temporary file, then streamed by slab";
        } else if (!fs::exists(data)) {
            throw InputError(path + ": its voxel data file " + data.string() + " does not exist");
        }
        const uint64_t have = fileBytes(data);
        if (have < mOffset + need) {
            std::ostringstream os;
            os << path << ": header/data size mismatch: the header describes " << sizeText(mGeometry.size) << " "
               << 8 * bytes << "-bit voxels (" << need << " bytes after " << mOffset << ") but "
               << (compressed ? "the decompressed data holds " : "the file holds ") << have << " bytes (truncated?)";
            throw InputError(os.str());
        }
        mFd = ::open(data.c_str(), O_RDONLY | O_CLOEXEC);
        if (mFd < 0) throw InputError(path + ": cannot open " + data.string() + ": " + std::strerror(errno));
        mRegular = true;
        for (int64_t k = 0; k < mGeometry.size[2]; ++k)
            mSliceOriginsMm.push_back(mGeometry.worldFromIndex({0, 0, double(k)}));
        mDescription = "NIfTI-2 (header by flyover with nifticlib's nifti2.h; ITK 5.2 reads NIfTI-1 only), " + how;
    }

    void addWarning(const std::string& text) { mWarnings.push_back(text); }

    ~Nifti2Source() override
    {
        if (mFd >= 0) ::close(mFd);
    }

    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const auto& s = mGeometry.size;
        if (!(0 <= k0 && k0 < k1 && k1 <= s[2])) throw std::out_of_range("readSlices: slice range");
        const std::size_t n = static_cast<std::size_t>(s[0] * s[1]) * static_cast<std::size_t>(k1 - k0);
        mSlab.resize(n * mComponentBytes);
        uint64_t pos = mOffset + static_cast<uint64_t>(s[0] * s[1] * k0) * mComponentBytes;
        std::size_t done = 0;
        while (done < mSlab.size()) {
            const ssize_t got = ::pread(mFd, mSlab.data() + done, mSlab.size() - done, static_cast<off_t>(pos + done));
            if (got < 0 && errno == EINTR) continue;
            if (got <= 0)
                throw InputError(mName + ": cannot read the voxel data: " +
                                 (got < 0 ? std::string(std::strerror(errno)) : std::string("the file ends early")));
            done += static_cast<std::size_t>(got);
        }
        if (mSwapped && mComponentBytes > 1)
            for (std::size_t i = 0; i < n; ++i) {
                char* v = mSlab.data() + i * mComponentBytes;
                std::reverse(v, v + mComponentBytes);
            }
        const std::size_t bad = toFloat(mSlab.data(), mType, n, out);
        if (bad < n) throwNonFinite(mName, s, k0, bad, out[bad]);
        if (mScaled)
            for (std::size_t i = 0; i < n; ++i) {
                out[i] = static_cast<float>(out[i] * mSlope + mInter);
                if (!std::isfinite(out[i])) throwNonFinite(mName, s, k0, i, out[i]);
            }
    }

private:
    std::unique_ptr<TempDir> mTemp;
    int mFd = -1;
    bool mSwapped = false;
    IOComponentEnum mType = IOComponentEnum::UNKNOWNCOMPONENTTYPE;
    std::size_t mComponentBytes = 0;
    uint64_t mOffset = 0;
    bool mScaled = false;
    double mSlope = 1, mInter = 0;
    std::vector<char> mSlab;
};

// ------------------------------------------------------------------ MetaImage header text

/// MetaIO (ITK 5.2) copies field names and values into fixed-size buffers, some of them
/// globals outside any sanitizer's view: a malformed line can corrupt the reading process
/// without crashing the header probe's child (found by fuzzing: a line with no '=' followed by
/// a long one; the parent later died in fflush). So the header text is checked here first,
/// without MetaIO: every line up to and including ElementDataFile is blank or
/// "Name = value" (or "Name: value") with a name of letters, digits and '_' (at most 64) and
/// printable text, at most 1024 characters per line, within the first 64 kB; and the voxel
/// data is binary (BinaryData absent or true).
void checkMetaImageHeaderText(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open: " + std::strerror(errno));
    std::string text(64 << 10, '\0');
    in.read(text.data(), std::streamsize(text.size()));
    text.resize(static_cast<std::size_t>(in.gcount()));
    std::size_t pos = 0;
    for (int line = 1; pos < text.size(); ++line) {
        std::size_t end = text.find('\n', pos);
        const bool complete = end != std::string::npos;
        if (!complete) end = text.size();
        std::string l = text.substr(pos, end - pos);
        pos = end + 1;
        if (!l.empty() && l.back() == '\r') l.pop_back();
        auto bad = [&](const std::string& why) {
            throw InputError(path + ": MetaImage header line " + std::to_string(line) + " " + why);
        };
        if (l.size() > 1024) bad("is longer than 1024 characters");
        for (unsigned char c : l)
            if (c != '\t' && (c < 32 || c > 126)) bad("holds a non-printable character");
        const std::string t = trim(l);
        if (t.empty()) continue;
        std::size_t n = 0;
        while (n < t.size() && (std::isalnum(static_cast<unsigned char>(t[n])) || t[n] == '_')) ++n;
        if (n == 0 || !std::isalpha(static_cast<unsigned char>(t[0]))) bad("does not start with a field name");
        if (n > 64) bad("has a field name longer than 64 characters");
        const std::size_t sep = t.find_first_not_of(" \t", n);
        if (sep == std::string::npos || (t[sep] != '=' && t[sep] != ':')) bad("is not 'Name = value'");
        const std::string name = t.substr(0, n), value = trim(t.substr(sep + 1));
        // ASCII voxel data (BinaryData false): MetaIO's region reader writes past the region's
        // buffer (found by fuzzing: heap corruption). MetaIO takes T, t or 1 for true.
        if (name == "BinaryData" && (value.empty() || std::string("Tt1").find(value[0]) == std::string::npos))
            bad("says BinaryData = " + value.substr(0, 20) + ": ASCII voxel data is not supported");
        if (name == "ElementDataFile") return;
        if (!complete) break;
    }
    throw InputError(path + ": MetaImage header has no ElementDataFile field in its first 64 kB");
}

// ------------------------------------------------------------- crash-isolated header probes

/// What a forked child did.
struct ChildOutcome {
    bool killed = false;  ///< by a signal: abort() in an assertion, a segfault
    int signal = 0;
    int exitCode = 0;
    std::string output;   ///< what it wrote to its pipe
};

void writeAll(int fd, const std::string& text)
{
    std::size_t done = 0;
    while (done < text.size()) {
        const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return;
        done += static_cast<std::size_t>(n);
    }
}

/// Runs `body(fd)` in a forked child that reports through the pipe `fd`. Debian builds GDCM
/// with assertions, and some malformed DICOM headers abort() inside it (found by fuzzing:
/// gdcm::ReadExplicitDataElement, "Should not happen"); header parsing therefore runs in a
/// child first, so that such a file is reported instead of taking flyover down. Parsing is
/// deterministic: what the child survived, the parent survives too. The child runs no TBB
/// and writes nothing to the console (FLYOVER_PROBE_STDERR=1 keeps its stderr, for debugging).
/// Address space a probing child may add to what it inherits: a malformed length field makes
/// GDCM allocate (and zero) hundreds of megabytes; with the cap the allocation fails quickly
/// instead. Not under AddressSanitizer, which reserves terabytes of shadow memory.
void capChildMemory(uint64_t extraBytes)
{
#if defined(__SANITIZE_ADDRESS__)
    const bool underAsan = true;
#elif defined(__has_feature)
    const bool underAsan = __has_feature(address_sanitizer);
#else
    const bool underAsan = false;
#endif
    if (underAsan) return;
    long pages = 0;
    if (std::FILE* f = std::fopen("/proc/self/statm", "r")) {
        if (std::fscanf(f, "%ld", &pages) != 1) pages = 0;
        std::fclose(f);
    }
    if (pages <= 0) return;
    const rlim_t limit = static_cast<rlim_t>(pages) * static_cast<rlim_t>(::sysconf(_SC_PAGESIZE)) + extraBytes;
    const rlimit as{limit, limit};
    ::setrlimit(RLIMIT_AS, &as);
}

template <typename Body>
ChildOutcome runInChild(uint64_t memoryCapBytes, Body&& body)
{
    int fds[2];
    if (::pipe(fds) != 0) throw InputError(std::string("cannot create a pipe: ") + std::strerror(errno));
    std::cout.flush();
    std::cerr.flush();
    std::fflush(nullptr);
    // One fork at a time: ITK's thread pool stops and restarts its threads in fork handlers,
    // which deadlocks when two threads fork at once.
    static std::mutex forkMutex;
    pid_t pid;
    {
        std::lock_guard<std::mutex> lock(forkMutex);
        pid = ::fork();
    }
    if (pid < 0) {
        ::close(fds[0]);
        ::close(fds[1]);
        throw InputError(std::string("cannot fork to check a header: ") + std::strerror(errno));
    }
    if (pid == 0) {
        ::close(fds[0]);
        for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL}) std::signal(sig, SIG_DFL);
        const rlimit noCore{0, 0};  // an abort in the child is expected: no core dump
        ::setrlimit(RLIMIT_CORE, &noCore);
        capChildMemory(memoryCapBytes);
        if (!std::getenv("FLYOVER_PROBE_STDERR")) {
            const int devnull = ::open("/dev/null", O_WRONLY);
            if (devnull >= 0) {
                ::dup2(devnull, STDOUT_FILENO);
                ::dup2(devnull, STDERR_FILENO);
            }
        }
        int code = 0;
        try {
            body(fds[1]);
        } catch (...) {
            code = 3;
        }
        ::_exit(code);
    }
    ::close(fds[1]);
    ChildOutcome out;
    char buf[1 << 14];
    for (;;) {
        const ssize_t n = ::read(fds[0], buf, sizeof buf);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) break;
        out.output.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fds[0]);
    int status = 0;
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    out.killed = WIFSIGNALED(status);
    out.signal = out.killed ? WTERMSIG(status) : 0;
    out.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : 0;
    return out;
}

std::string signalText(int sig)
{
    const char* name = ::strsignal(sig);
    return std::string(name ? name : "signal") + ", signal " + std::to_string(sig);
}

/// The reader for a file: chosen by extension for NIfTI, NRRD and MetaImage (so that other
/// readers never parse those files), else by asking every registered reader (DICOM files
/// often have no extension).
itk::ImageIOBase::Pointer createIo(const std::string& path)
{
    CapturedOutput capture;
    const std::string format = formatFromName(path);
    itk::ImageIOBase::Pointer io;
    if (format == "NIfTI") io = itk::NiftiImageIO::New();
    else if (format == "NRRD") io = itk::NrrdImageIO::New();
    else if (format == "MetaImage") io = itk::MetaImageIO::New();
    else return itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::CommonEnums::IOFileMode::ReadMode);
    return io->CanReadFile(path.c_str()) ? io : nullptr;
}

/// Every header is parsed in a child first, and its verdict stands: the parent only parses
/// what the child parsed without trouble. Besides GDCM's assertions, fuzzing found a buffer
/// overflow in ITK's MetaIO (a long field name; strcpy in MET_InitReadField, stopped by
/// glibc's fortify checks with abort()). Returns "" when the child read the header, "NOIO"
/// when no reader accepted the file, else the problem in words.
std::string probeHeaderInChild(const std::string& path)
{
    const std::string format = formatFromName(path);
    const std::string reader = format == "NIfTI"       ? "NIfTI reader (ITK's niftilib)"
                               : format == "NRRD"      ? "NRRD reader (ITK's NrrdIO)"
                               : format == "MetaImage" ? "MetaImage reader (ITK's MetaIO)"
                                                       : "image reader (ITK; GDCM for DICOM)";
    const ChildOutcome child = runInChild(2 * fileBytes(path) + (uint64_t(512) << 20), [&](int fd) {
        std::string verdict = "OK";
        itk::ImageIOBase::Pointer io;
        try {
            io = createIo(path);
            if (!io) {
                verdict = "NOIO";
            } else {
                CapturedOutput capture;
                io->SetFileName(path);
                io->ReadImageInformation();
            }
        } catch (const itk::ExceptionObject& e) {
            verdict = "ERR cannot read the " + (io ? formatOfIo(*io) : format) + " header: " + itkReason(e);
        } catch (const std::exception& e) {
            verdict = "ERR cannot read the " + (io ? formatOfIo(*io) : format) + " header: " + e.what();
        }
        writeAll(fd, verdict);
    });
    if (child.killed)
        return "malformed file: the " + reader + " crashed on its header (" + signalText(child.signal) + ")";
    if (child.exitCode != 0)
        throw std::runtime_error(path + ": header probe exited with code " + std::to_string(child.exitCode));
    if (child.output == "NOIO") return "NOIO";
    if (child.output.rfind("ERR ", 0) == 0) return child.output.substr(4);
    return "";
}

void readInformation(itk::ImageIOBase& io, const std::string& path, const std::string& name)
{
    try {
        CapturedOutput capture;
        io.SetFileName(path);
        io.ReadImageInformation();
    } catch (const itk::ExceptionObject& e) {
        throw InputError(name + ": cannot read the " + formatOfIo(io) + " header: " + itkReason(e));
    }
}

std::unique_ptr<ImageSource> openFile(const std::string& path, const ImageReadOptions& options)
{
    if (fileBytes(path) == 0) throw InputError(path + ": the file is empty");
    if (formatFromName(path) == "MetaImage") checkMetaImageHeaderText(path);
    const std::string probe = probeHeaderInChild(path);
    if (!probe.empty() && probe != "NOIO") throw InputError(path + ": " + probe);
    itk::ImageIOBase::Pointer io = probe == "NOIO" ? nullptr : createIo(path);
    if (!io) {
        const std::string format = formatFromName(path);
        if (format == "NIfTI" && isNifti2(path)) {
            auto source = std::make_unique<Nifti2Source>(path);
            if (!options.dicomSeriesUid.empty())
                source->addWarning(path + ": a DICOM series UID (" + options.dicomSeriesUid +
                                   ") only selects within a DICOM folder; ignored for a single file");
            return source;
        }
        if (!format.empty())
            throw InputError(path + ": not a readable " + format + " file (its header is corrupt, truncated or "
                                    "of another format)");
        throw InputError(path + ": not a readable image (supported: NIfTI .nii/.nii.gz, NRRD .nrrd/.nhdr, "
                                "MetaImage .mha/.mhd, DICOM file or series folder)");
    }
    readInformation(*io, path, path);
    const std::string format = formatOfIo(*io);
    ImageGeometry g = checkHeader(*io, path);
    if (format == "NIfTI") {
        // ITK 5.2 turns metre and micron spacing into mm but leaves qoffset/srow offsets in
        // the file's unit (measured: tests/volume/nifti2_test.cpp): scale the origin too.
        const int units = std::atoi(metaString(*io, "xyzt_units").c_str()) & 0x07;
        const double unit = units == 1 ? 1000.0 : units == 3 ? 0.001 : 1.0;
        for (int c = 0; c < 3; ++c) g.originMm[c] *= unit;
    }
    const std::string typeName = itk::ImageIOBase::GetComponentTypeAsString(io->GetComponentType());
    const DataFile data = dataFileOf(*io, path);
    checkDataSize(data, path, g, typeName);

    std::unique_ptr<TempDir> temp;
    bool streamed = false;
    std::string how;
    if (format == "NIfTI") {
        streamed = true;
        how = "streamed by slab";
        if (data.compressed) {
            // ITK would re-inflate the file from its start for every region: inflate it
            // once into a temporary uncompressed copy and stream from that.
            temp = std::make_unique<TempDir>();
            fs::path copy;
            if (data.path == fs::path(path)) {
                copy = temp->path() / "scan.nii";
            } else {  // an Analyze-style pair: NAME.hdr + NAME.img.gz
                if (!endsWith(lowerCase(path), ".hdr"))
                    throw InputError(path + ": open the .hdr file of a .hdr/.img.gz pair");
                fs::copy_file(path, temp->path() / "scan.hdr");
                copy = temp->path() / "scan.img";
            }
            gunzipFile(data.path, copy, data.offset + data.bytes, path);
            const fs::path readPath = data.path == fs::path(path) ? copy : temp->path() / "scan.hdr";
            io = createIo(readPath.string());
            if (!io) throw InputError(path + ": the decompressed NIfTI header is unreadable");
            readInformation(*io, readPath.string(), path);
            how = "gunzipped by zlib to a temporary file, then streamed by slab";
        }
    } else if (format == "MetaImage" && io->CanStreamRead()) {
        streamed = true;
        how = "streamed by slab";
    } else {
        how = "read whole in its native type (" + typeName + "; " + format + " cannot be read by region)";
    }
    const std::string description = format + " via ITK " + io->GetNameOfClass() + ", " + how;
    auto source = std::make_unique<FileSource>(path, io, g, streamed, std::move(temp), description);
    if (!options.dicomSeriesUid.empty())
        source->addWarning(path + ": a DICOM series UID (" + options.dicomSeriesUid +
                           ") only selects within a DICOM folder; ignored for a single file");
    return source;
}

// --------------------------------------------------------------------------- DICOM series

/// What one DICOM file's header says (read by ITK's GDCMImageIO).
struct DicomFile {
    std::string path;
    bool readable = false;     ///< the header was read (series, position, ... are known)
    bool incomplete = false;   ///< readable, but its pixel data is cut short
    std::string problem;       ///< why it could not be read
    std::string seriesUid;
    std::string instance;      ///< Instance Number, for messages
    std::string tiltTag;       ///< Gantry/Detector Tilt (0018,1120), degrees, as written
    bool hasPosition = false, hasOrientation = false, hasPixelSpacing = false;
    Vec3d positionMm;          ///< Image Position (Patient), LPS
    Vec3d rowDir, colDir;      ///< directions of increasing column (i) and row (j) index
    double spacingI = 0, spacingJ = 0;
    int64_t nx = 0, ny = 0, frames = 1;
    unsigned components = 1;
};

bool hasDicmPreamble(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    char b[132];
    return in.read(b, 132) && std::memcmp(b + 128, "DICM", 4) == 0;
}

DicomFile scanDicomFile(const std::string& path)
{
    DicomFile f;
    f.path = path;
    auto io = itk::GDCMImageIO::New();
    try {
        io->SetFileName(path);
        io->ReadImageInformation();
    } catch (const itk::ExceptionObject& e) {
        f.problem = itkReason(e);
        return f;
    } catch (const std::exception& e) {  // e.g. bad_alloc from a length field gone wild
        f.problem = e.what();
        return f;
    }
    f.readable = true;
    auto tag = [&](const char* t) {
        std::string v;
        return io->GetValueFromTag(t, v) ? trim(v) : std::string();
    };
    f.seriesUid = tag("0020|000e");
    f.instance = tag("0020|0013");
    f.tiltTag = tag("0018|1120");
    f.hasPosition = !tag("0020|0032").empty();
    f.hasOrientation = !tag("0020|0037").empty();
    f.hasPixelSpacing = !tag("0028|0030").empty();
    const unsigned dims = io->GetNumberOfDimensions();
    for (int c = 0; c < 3; ++c) f.positionMm[c] = c < int(dims) ? io->GetOrigin(c) : 0.0;
    const auto d0 = io->GetDirection(0), d1 = io->GetDirection(1);
    for (int r = 0; r < 3; ++r) {
        f.rowDir[r] = r < int(d0.size()) ? d0[r] : 0.0;
        f.colDir[r] = r < int(d1.size()) ? d1[r] : 0.0;
    }
    f.spacingI = io->GetSpacing(0);
    f.spacingJ = io->GetSpacing(1);
    f.nx = static_cast<int64_t>(io->GetDimensions(0));
    f.ny = static_cast<int64_t>(io->GetDimensions(1));
    f.frames = dims >= 3 ? static_cast<int64_t>(io->GetDimensions(2)) : 1;
    f.components = io->GetNumberOfComponents();
    return f;
}

/// GDCM reports cut pixel data only as a console warning.
bool saysIncompletePixelData(const std::string& chatter)
{
    return chatter.find("Incomplete Pixel Data") != std::string::npos;
}

/// Runs `work(i)` for i in [0, n) in parallel; when GDCM complained about truncated pixel
/// data, runs again one by one to name the files. Returns their indices (usually none).
template <typename Work>
std::vector<std::size_t> parallelFindIncomplete(std::size_t n, Work&& work)
{
    std::string chatter;
    {
        CapturedOutput capture;
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) { work(i); });
        chatter = capture.take();
    }
    std::vector<std::size_t> found;
    if (!saysIncompletePixelData(chatter)) return found;
    for (std::size_t i = 0; i < n; ++i) {
        CapturedOutput capture;
        work(i);
        if (saysIncompletePixelData(capture.take())) found.push_back(i);
    }
    return found;
}

std::string fileName(const std::string& path) { return fs::path(path).filename().string(); }

// A DicomFile as one tab-separated line, to come back from a probing child.
std::string oneField(std::string s)
{
    std::replace_if(s.begin(), s.end(), [](char c) { return c == '\t' || c == '\n' || c == '\r'; }, ' ');
    return s;
}

std::string serializeDicomFile(std::size_t index, const DicomFile& f)
{
    std::ostringstream os;
    os.precision(17);
    os << "R\t" << index << '\t' << f.readable << '\t' << f.incomplete << '\t' << oneField(f.problem) << '\t'
       << oneField(f.seriesUid) << '\t' << oneField(f.instance) << '\t' << oneField(f.tiltTag) << '\t'
       << f.hasPosition << '\t' << f.hasOrientation << '\t' << f.hasPixelSpacing;
    for (const Vec3d* v : {&f.positionMm, &f.rowDir, &f.colDir}) os << '\t' << v->x << '\t' << v->y << '\t' << v->z;
    os << '\t' << f.spacingI << '\t' << f.spacingJ << '\t' << f.nx << '\t' << f.ny << '\t' << f.frames << '\t'
       << f.components << '\n';
    return os.str();
}

/// Parses one "R" line into files[index]; false when malformed.
bool parseDicomFile(const std::string& line, std::vector<DicomFile>& files)
{
    std::vector<std::string> v;
    std::size_t start = 0;
    for (;;) {
        const auto tab = line.find('\t', start);
        v.push_back(line.substr(start, tab == std::string::npos ? std::string::npos : tab - start));
        if (tab == std::string::npos) break;
        start = tab + 1;
    }
    if (v.size() != 26 || v[0] != "R") return false;
    const std::size_t index = std::stoul(v[1]);
    if (index >= files.size()) return false;
    DicomFile& f = files[index];
    auto num = [&](int i) { return std::strtod(v[std::size_t(i)].c_str(), nullptr); };
    f.readable = v[2] == "1";
    f.incomplete = v[3] == "1";
    f.problem = v[4];
    f.seriesUid = v[5];
    f.instance = v[6];
    f.tiltTag = v[7];
    f.hasPosition = v[8] == "1";
    f.hasOrientation = v[9] == "1";
    f.hasPixelSpacing = v[10] == "1";
    f.positionMm = {num(11), num(12), num(13)};
    f.rowDir = {num(14), num(15), num(16)};
    f.colDir = {num(17), num(18), num(19)};
    f.spacingI = num(20);
    f.spacingJ = num(21);
    f.nx = std::atoll(v[22].c_str());
    f.ny = std::atoll(v[23].c_str());
    f.frames = std::atoll(v[24].c_str());
    f.components = static_cast<unsigned>(std::atol(v[25].c_str()));
    return true;
}

/// Reads every file's header, in forked children (one per core, each on a contiguous share
/// of the files): a file that makes GDCM abort is marked unreadable, and the scan goes on
/// after it in a new child.
std::vector<DicomFile> scanDicomFiles(const std::vector<std::string>& paths)
{
    std::vector<DicomFile> files(paths.size());
    for (std::size_t i = 0; i < paths.size(); ++i) files[i].path = paths[i];
    const std::size_t workers = std::max<std::size_t>(
        1, std::min<std::size_t>({paths.size(), std::max(1u, std::thread::hardware_concurrency()), 8}));
    std::vector<std::string> failures(workers);
    std::vector<std::thread> threads;
    for (std::size_t w = 0; w < workers; ++w) {
        const std::size_t begin = paths.size() * w / workers, end = paths.size() * (w + 1) / workers;
        threads.emplace_back([&, w, begin, end] {
            std::size_t next = begin;
            while (next < end) {
                uint64_t largest = 0;
                for (std::size_t i = next; i < end; ++i) largest = std::max(largest, fileBytes(paths[i]));
                const ChildOutcome child = runInChild(2 * largest + (uint64_t(512) << 20), [&](int fd) {
                    for (std::size_t i = next; i < end; ++i) {
                        writeAll(fd, "S\t" + std::to_string(i) + "\n");
                        CapturedOutput capture;
                        DicomFile f = scanDicomFile(paths[i]);
                        f.incomplete = f.readable && saysIncompletePixelData(capture.take());
                        writeAll(fd, serializeDicomFile(i, f));
                    }
                });
                std::size_t started = end, finished = next;
                bool lastDone = true;
                std::istringstream lines(child.output);
                std::string line;
                while (std::getline(lines, line)) {
                    if (line.rfind("S\t", 0) == 0) {
                        started = std::stoul(line.substr(2));
                        lastDone = false;
                    } else if (parseDicomFile(line, files)) {
                        finished = started + 1;
                        lastDone = true;
                    }
                }
                if (child.killed && !lastDone && started < end) {
                    files[started].readable = false;
                    files[started].problem = "malformed file: the DICOM reader (GDCM) aborted on it (" +
                                             signalText(child.signal) + ")";
                    next = started + 1;
                } else if (child.killed || child.exitCode != 0 || finished < end) {
                    failures[w] = "DICOM header scan stopped at " + paths[std::min(finished, end - 1)] + " (child " +
                                  (child.killed ? signalText(child.signal) : "exit code " + std::to_string(child.exitCode)) + ")";
                    return;
                } else {
                    next = end;
                }
            }
        });
    }
    for (auto& t : threads) t.join();
    for (const auto& f : failures)
        if (!f.empty()) throw std::runtime_error(f);
    return files;
}

std::string uidText(const std::string& uid) { return uid.empty() ? "(no Series Instance UID)" : uid; }

class DicomSeriesSource final : public ImageSource {
public:
    DicomSeriesSource(const std::string& dir, std::vector<DicomFile> slices, const ImageGeometry& g, bool regular,
                      std::vector<Vec3d> origins, std::vector<std::string> warnings, const std::string& uid)
        : mFiles(std::move(slices))
    {
        mName = dir;
        mGeometry = g;
        mRegular = regular;
        mSliceOriginsMm = std::move(origins);
        mWarnings = std::move(warnings);
        mDescription = "DICOM series " + uidText(uid) + " (" + std::to_string(mFiles.size()) +
                       " files) via ITK GDCMImageIO (GDCM), read file by file";
    }

    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const auto& s = mGeometry.size;
        if (!(0 <= k0 && k0 < k1 && k1 <= s[2])) throw std::out_of_range("readSlices: slice range");
        const std::size_t count = static_cast<std::size_t>(k1 - k0);
        const std::size_t perSlice = static_cast<std::size_t>(s[0] * s[1]);
        std::vector<std::string> errors(count);
        std::vector<std::size_t> badVoxel(count, perSlice);
        // Decoding (JPEG 2000 above all) dominates: one file per task.
        const auto incomplete = parallelFindIncomplete(count, [&](std::size_t n) {
            errors[n] = readOne(mFiles[static_cast<std::size_t>(k0) + n].path, out + n * perSlice, badVoxel[n]);
        });
        if (!incomplete.empty())
            throw InputError(mFiles[static_cast<std::size_t>(k0) + incomplete.front()].path +
                             ": pixel data is incomplete (the file is truncated)");
        for (std::size_t n = 0; n < count; ++n) {
            if (!errors[n].empty()) throw InputError(errors[n]);
            if (badVoxel[n] < perSlice)
                throwNonFinite(mFiles[static_cast<std::size_t>(k0) + n].path, s, k0 + int64_t(n), badVoxel[n],
                               out[n * perSlice + badVoxel[n]]);
        }
    }

private:
    /// Reads one slice file (GDCMImageIO applies Rescale Slope/Intercept); returns an error
    /// message or "" and sets `bad` to the first non-finite voxel.
    std::string readOne(const std::string& path, float* out, std::size_t& bad) const
    {
        const auto& s = mGeometry.size;
        auto io = itk::GDCMImageIO::New();
        try {
            io->SetFileName(path);
            io->ReadImageInformation();
            if (static_cast<int64_t>(io->GetDimensions(0)) != s[0] || static_cast<int64_t>(io->GetDimensions(1)) != s[1])
                return path + ": slice size changed since the series was scanned";
            const std::size_t n = static_cast<std::size_t>(s[0] * s[1]);
            const std::size_t bytes = componentBytes(io->GetComponentType());
            if (bytes == 0 || io->GetNumberOfComponents() != 1)
                return path + ": unsupported pixel type " +
                       itk::ImageIOBase::GetComponentTypeAsString(io->GetComponentType());
            std::vector<char> native(n * bytes);
            itk::ImageIORegion region(io->GetNumberOfDimensions());
            for (unsigned d = 0; d < io->GetNumberOfDimensions(); ++d) {
                region.SetIndex(d, 0);
                region.SetSize(d, io->GetDimensions(d));
            }
            io->SetIORegion(region);
            io->Read(native.data());
            bad = toFloat(native.data(), io->GetComponentType(), n, out);
        } catch (const itk::ExceptionObject& e) {
            return path + ": cannot decode the pixel data: " + itkReason(e);
        }
        return "";
    }

    std::vector<DicomFile> mFiles;  // in slice order
};

std::unique_ptr<ImageSource> openDicomFolder(const std::string& dir, const ImageReadOptions& options)
{
    std::vector<std::string> paths;
    std::error_code ec;
    for (auto it = fs::recursive_directory_iterator(dir, fs::directory_options::skip_permission_denied, ec);
         !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
        const std::string name = it->path().filename().string();
        if (!name.empty() && name[0] == '.') {
            if (it->is_directory()) it.disable_recursion_pending();
            continue;
        }
        if (it->is_regular_file() && lowerCase(name) != "dicomdir") paths.push_back(it->path().string());
    }
    if (ec) throw InputError(dir + ": cannot list the folder: " + ec.message());
    std::sort(paths.begin(), paths.end());
    if (paths.empty()) throw InputError(dir + ": the folder is empty (expected a DICOM series)");

    std::vector<DicomFile> files = scanDicomFiles(paths);

    // Series by UID; files that are not DICOM images are ignored, DICOM ones that fail are
    // reported when they matter.
    std::map<std::string, std::vector<std::size_t>> series;
    std::vector<std::size_t> broken;
    for (std::size_t i = 0; i < files.size(); ++i) {
        if (files[i].readable) series[files[i].seriesUid].push_back(i);
        else if (hasDicmPreamble(files[i].path)) broken.push_back(i);
    }
    auto brokenNote = [&]() -> std::string {
        if (broken.empty()) return "";
        const DicomFile& b = files[broken.front()];
        return "; " + std::to_string(broken.size()) + " DICOM file(s) could not be read, e.g. " + b.path + ": " +
               b.problem;
    };
    if (series.empty()) {
        if (!broken.empty())
            throw InputError(files[broken.front()].path + ": unreadable DICOM file: " + files[broken.front()].problem);
        throw InputError(dir + ": no DICOM image found in the folder");
    }
    std::string chosen;
    std::vector<std::string> warnings;
    std::string list;
    for (const auto& [uid, idx] : series)
        list += (list.empty() ? "" : ", ") + uidText(uid) + " (" + std::to_string(idx.size()) + " files)";
    if (!options.dicomSeriesUid.empty()) {
        if (!series.count(options.dicomSeriesUid))
            throw InputError(dir + ": no DICOM series " + options.dicomSeriesUid + " in the folder (it holds: " + list + ")");
        chosen = options.dicomSeriesUid;
    } else {
        std::size_t best = 0;
        for (const auto& [uid, idx] : series)
            if (idx.size() > best) { best = idx.size(); chosen = uid; }
        if (series.size() > 1)
            warnings.push_back(dir + " holds " + std::to_string(series.size()) + " series: " + list + "; reading " +
                               uidText(chosen) + ", the one with the most files (choose with --series UID)");
    }
    std::vector<DicomFile> sl;
    for (std::size_t i : series[chosen]) sl.push_back(files[i]);

    // One multi-frame file is a volume of its own.
    if (sl.size() == 1 && sl.front().frames > 1) return openFile(sl.front().path, options);
    for (const auto& f : sl) {
        if (f.incomplete) throw InputError(f.path + ": pixel data is incomplete (the file is truncated)");
        if (f.frames > 1)
            throw InputError(f.path + ": a multi-frame file (" + std::to_string(f.frames) + " frames) inside a "
                             "series of single-frame files is not supported");
        if (f.components != 1)
            throw InputError(f.path + ": pixel type has " + std::to_string(f.components) +
                             " components (colour?); a scalar (grey-value) CT is needed");
        if (!f.hasPosition || !f.hasOrientation)
            throw InputError(f.path + ": no Image Position/Orientation (Patient) (0020,0032)/(0020,0037): "
                                      "its place in the volume is unknown (a secondary capture?)");
        if (!f.hasPixelSpacing)
            throw InputError(f.path + ": no Pixel Spacing (0028,0030): the in-plane voxel size is unknown");
    }
    if (sl.size() < 2)
        throw InputError(dir + ": DICOM series " + uidText(chosen) + " has a single slice (" + fileName(sl[0].path) +
                         "); image is 2D, a 3D volume is needed" + brokenNote());

    const DicomFile& ref = sl.front();
    for (const auto& f : sl) {
        const bool same = f.nx == ref.nx && f.ny == ref.ny && length(f.rowDir - ref.rowDir) < 1e-4 &&
                          length(f.colDir - ref.colDir) < 1e-4 &&
                          std::fabs(f.spacingI - ref.spacingI) <= 1e-4 * ref.spacingI &&
                          std::fabs(f.spacingJ - ref.spacingJ) <= 1e-4 * ref.spacingJ;
        if (!same)
            throw InputError(dir + ": series " + uidText(chosen) + " mixes slice sizes, pixel spacings or "
                             "orientations (" + fileName(ref.path) + " vs " + fileName(f.path) + ")");
    }
    const Vec3d u = normalize(ref.rowDir), v = normalize(ref.colDir);
    const Vec3d n = normalize(cross(u, v));
    // Order by position along the slice normal: never by file name or Instance Number.
    std::sort(sl.begin(), sl.end(),
              [&](const DicomFile& a, const DicomFile& b) { return dot(a.positionMm, n) < dot(b.positionMm, n); });
    const std::size_t count = sl.size();
    std::vector<double> t(count), steps;
    for (std::size_t k = 0; k < count; ++k) t[k] = dot(sl[k].positionMm - sl[0].positionMm, n);
    auto where = [&](std::size_t k) {
        return fileName(sl[k].path) + (sl[k].instance.empty() ? "" : " (#" + sl[k].instance + ")");
    };
    for (std::size_t k = 0; k + 1 < count; ++k) {
        const double d = t[k + 1] - t[k];
        if (!(d > 1e-3)) {
            std::ostringstream os;
            os << dir << ": two slices at the same position along the slice normal: " << where(k) << " and "
               << where(k + 1) << " (several acquisitions or time points in one series?)";
            throw InputError(os.str());
        }
        steps.push_back(d);
    }
    std::vector<double> sorted = steps;
    std::nth_element(sorted.begin(), sorted.begin() + long(sorted.size() / 2), sorted.end());
    const double median = sorted[sorted.size() / 2];
    // Slice positions are written as decimal strings with a few digits: allow 2% of a step.
    const double tolerance = std::max(0.02, 0.02 * median);
    int uneven = 0;
    std::ostringstream firstUneven;
    for (std::size_t k = 0; k + 1 < count; ++k) {
        const double d = steps[k];
        if (std::fabs(d - median) <= tolerance) continue;
        if (uneven++ > 0) continue;
        const double ratio = d / median;
        const long whole = std::lround(ratio);
        firstUneven.precision(4);
        if (whole >= 2 && std::fabs(d - double(whole) * median) <= tolerance)
            firstUneven << (whole - 1) << " slice(s) missing between " << where(k) << " and " << where(k + 1)
                        << " (" << d << " mm apart; the series steps " << median << " mm)";
        else
            firstUneven << "uneven slice spacing: " << d << " mm between " << where(k) << " and " << where(k + 1)
                        << ", " << median << " mm elsewhere";
    }
    std::string unevenText = firstUneven.str();
    if (uneven > 1) unevenText += " (and " + std::to_string(uneven - 1) + " more uneven step(s))";
    if (uneven > 0 && !options.allowGaps)
        throw InputError(dir + ": " + unevenText + "; refusing to guess the geometry (--allow-gaps interpolates "
                         "across gaps at the true slice positions)" + brokenNote());
    if (uneven > 0)
        warnings.push_back(dir + ": " + unevenText + "; accepted (--allow-gaps): voxels between these slices are "
                           "interpolated linearly at the true slice positions");

    // Gantry tilt: slice positions drift sideways of the slice normal.
    double lateralMax = 0;
    for (std::size_t k = 0; k < count; ++k) {
        const Vec3d e = (sl[k].positionMm - sl[0].positionMm) - t[k] * n;
        lateralMax = std::max(lateralMax, length(e));
    }
    const double lateralTolerance = std::max(0.01, 0.05 * std::min(ref.spacingI, ref.spacingJ));
    const bool tilted = lateralMax > lateralTolerance;
    if (tilted) {
        const Vec3d e = (sl[count - 1].positionMm - sl[0].positionMm) - t[count - 1] * n;
        const double deg = std::atan2(length(e), t[count - 1]) * 180.0 / 3.14159265358979323846;
        std::ostringstream os;
        os.precision(3);
        os << dir << ": gantry tilt of " << deg << " degrees (slice positions drift " << length(e)
           << " mm sideways over " << t[count - 1] << " mm"
           << (ref.tiltTag.empty() ? std::string() : "; Gantry/Detector Tilt = " + ref.tiltTag)
           << "): corrected by sampling every slice at its true position on a grid aligned with the slice planes";
        warnings.push_back(os.str());
    }

    ImageGeometry g;
    g.size = {ref.nx, ref.ny, static_cast<int64_t>(count)};
    const bool regular = uneven == 0 && !tilted;
    // The mean step, rounded to 1 nm: positions are decimal strings, and the rounding keeps
    // a 1.5 mm series at exactly 1.5 (as NIfTI or NRRD would hold it), not 1.4999999999.
    const double meanStep = std::round(t[count - 1] / double(count - 1) * 1e6) / 1e6;
    g.spacingMm = {ref.spacingI, ref.spacingJ, regular ? meanStep : median};
    g.originMm = sl[0].positionMm;
    for (int r = 0; r < 3; ++r) {
        g.direction[r][0] = u[r];
        g.direction[r][1] = v[r];
        g.direction[r][2] = n[r];
    }
    validateGeometry(g, dir);
    std::vector<Vec3d> origins;
    for (const auto& f : sl) origins.push_back(f.positionMm);
    return std::make_unique<DicomSeriesSource>(dir, std::move(sl), g, regular, std::move(origins), std::move(warnings),
                                               chosen);
}

// -------------------------------------------------------------------------------- writing

template <typename T>
void writeImageImpl(const Image3<T>& image, const std::string& path)
{
    registerImageIO();
    using ItkImage = itk::Image<T, 3>;
    auto itkImage = ItkImage::New();
    typename ItkImage::RegionType region;
    typename ItkImage::SpacingType spacing;
    typename ItkImage::PointType origin;
    typename ItkImage::DirectionType direction;
    const auto& g = image.geometry;
    for (int c = 0; c < 3; ++c) {
        region.SetSize(c, static_cast<itk::SizeValueType>(g.size[c]));
        spacing[c] = g.spacingMm[c];
        origin[c] = g.originMm[c];
        for (int r = 0; r < 3; ++r) direction[r][c] = g.direction[r][c];
    }
    if (static_cast<int64_t>(image.voxels.size()) != g.voxelCount())
        throw InputError(path + ": image buffer size does not match its dimensions");
    itkImage->SetRegions(region);
    itkImage->SetSpacing(spacing);
    itkImage->SetOrigin(origin);
    itkImage->SetDirection(direction);
    // ITK wants a mutable buffer it does not own.
    itkImage->GetPixelContainer()->SetImportPointer(const_cast<T*>(image.voxels.data()),
                                                    image.voxels.size(), false);

    // Temporary name in the same folder with the same extension(s), then an atomic rename.
    const fs::path target(path);
    const std::string name = target.filename().string();
    const fs::path tmp = target.parent_path() /
                         (".tmp-" + std::to_string(::getpid()) + "-" + name);
    try {
        CapturedOutput capture;
        auto writer = itk::ImageFileWriter<ItkImage>::New();
        writer->SetFileName(tmp.string());
        writer->SetInput(itkImage);
        writer->SetUseCompression(true);
        writer->Update();
    } catch (const itk::ExceptionObject& e) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + itkReason(e));
    }
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) {
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + ec.message());
    }
}

} // namespace

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

void writeImage(const Image3<int16_t>& image, const std::string& path) { writeImageImpl(image, path); }
void writeImage(const Image3<uint8_t>& image, const std::string& path) { writeImageImpl(image, path); }

} // namespace flyover
