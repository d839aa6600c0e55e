// NIfTI-1 voxels read by flyover (volume/io/nifti1.h, raw_voxels.h: pread, or inflated while
// read) must be exactly what ITK's NiftiImageIO gives for the same file: every voxel type,
// both byte orders, with and without scl_slope/scl_inter, plain and gzipped. Also: a gzip
// stream that ends early, and a source closed while its reading thread is ahead of it; gzip
// members, trailing bytes and uncompressed .nii.gz read as zlib's gzread reads them; corrupt
// and cut gzip data refused.

#include "volume/error.h"
#include "volume/image_io.h"

#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkNiftiImageIO.h>
#include <nifti/nifti1.h>

#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

struct Dir {
    fs::path path;
    explicit Dir(const std::string& tag)
        : path(fs::temp_directory_path() / ("flyover-nifti1-" + tag + "-" + std::to_string(::getpid())))
    {
        fs::remove_all(path);
        fs::create_directories(path);
    }
    ~Dir() { fs::remove_all(path); }
};

template <typename T>
void reverseBytes(T& v)
{
    auto* b = reinterpret_cast<unsigned char*>(&v);
    std::reverse(b, b + sizeof(T));
}

/// A value of voxel (i, j, k) in the range of type T, signs and large magnitudes included.
template <typename T>
T pattern(int i, int j, int k)
{
    const long long n = i * 7 + j * 131 + k * 1031;
    if constexpr (std::is_floating_point_v<T>) return T((n % 2000) * 0.37 - 250.25);
    else if constexpr (sizeof(T) == 1) return T(n % 251 + (std::is_signed_v<T> ? -125 : 0));
    else if constexpr (sizeof(T) == 2) return T(n * 37 % 60000 + (std::is_signed_v<T> ? -30000 : 0));
    else if constexpr (sizeof(T) == 4) return T(n * 2654435 % 4000000000LL + (std::is_signed_v<T> ? -2000000000LL : 0));
    else return T(n * 976369LL * 1024 + (std::is_signed_v<T> ? -(1LL << 40) : 0));
}

struct Layout {
    int nx = 9, ny = 7, nz = 5;
    bool bigEndian = false;
    float slope = 0, inter = 0;
};

/// A .nii file (header, 4 bytes of extension flag, voxels), in either byte order.
template <typename T>
std::vector<char> niftiBytes(short datatype, const Layout& l)
{
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    std::memcpy(h.magic, "n+1\0", 4);
    h.datatype = datatype;
    h.bitpix = short(8 * sizeof(T));
    const short dims[8] = {3, short(l.nx), short(l.ny), short(l.nz), 1, 1, 1, 1};
    std::memcpy(h.dim, dims, sizeof dims);
    const float pixdim[4] = {1, 0.7f, 0.8f, 1.5f};
    std::memcpy(h.pixdim, pixdim, sizeof pixdim);
    h.vox_offset = 352;
    h.scl_slope = l.slope;
    h.scl_inter = l.inter;
    h.xyzt_units = 2;
    if (l.bigEndian) {
        reverseBytes(h.sizeof_hdr);
        for (auto& d : h.dim) reverseBytes(d);
        reverseBytes(h.datatype);
        reverseBytes(h.bitpix);
        for (auto& p : h.pixdim) reverseBytes(p);
        reverseBytes(h.vox_offset);
        reverseBytes(h.scl_slope);
        reverseBytes(h.scl_inter);
    }
    std::vector<char> bytes(352 + sizeof(T) * std::size_t(l.nx * l.ny * l.nz), 0);
    std::memcpy(bytes.data(), &h, sizeof h);
    std::size_t at = 352;
    for (int k = 0; k < l.nz; ++k)
        for (int j = 0; j < l.ny; ++j)
            for (int i = 0; i < l.nx; ++i) {
                T v = pattern<T>(i, j, k);
                if (l.bigEndian) reverseBytes(v);
                std::memcpy(bytes.data() + at, &v, sizeof(T));
                at += sizeof(T);
            }
    return bytes;
}

void writePlain(const fs::path& p, const std::vector<char>& bytes)
{
    std::ofstream(p, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
}

void writeGzip(const fs::path& p, const std::vector<char>& bytes)
{
    gzFile f = ::gzopen(p.c_str(), "wb6");
    ASSERT_NE(f, nullptr);
    ASSERT_EQ(::gzwrite(f, bytes.data(), unsigned(bytes.size())), int(bytes.size()));
    ::gzclose(f);
}

/// ITK's own reading of the file, as float (the reference).
std::vector<float> itkVoxels(const fs::path& p)
{
    using Image = itk::Image<float, 3>;
    auto reader = itk::ImageFileReader<Image>::New();
    reader->SetImageIO(itk::NiftiImageIO::New());
    reader->SetFileName(p.string());
    reader->Update();
    const Image* img = reader->GetOutput();
    const auto n = img->GetLargestPossibleRegion().GetNumberOfPixels();
    return std::vector<float>(img->GetBufferPointer(), img->GetBufferPointer() + n);
}

/// Checks every voxel of flyover's reading against ITK's, bit for bit (NaN never occurs).
void expectSameAsItk(const fs::path& p, bool byFlyover)
{
    const std::vector<float> itk = itkVoxels(p);
    auto source = openImage(p.string());
    EXPECT_EQ(source->description().find("by flyover") != std::string::npos, byFlyover)
        << p.filename() << ": " << source->description();
    const Image3<float> ours = readImage(p.string());
    ASSERT_EQ(ours.voxels.size(), itk.size()) << p.filename();
    std::size_t differ = 0, first = itk.size();
    for (std::size_t n = 0; n < itk.size(); ++n)
        if (std::memcmp(&ours.voxels[n], &itk[n], sizeof(float)) != 0 && differ++ == 0) first = n;
    EXPECT_EQ(differ, 0u) << p.filename() << ": " << differ << " voxels differ from ITK's, the first #" << first
                          << ": flyover " << ours.voxels[first] << ", ITK " << itk[first];
}

template <typename T>
void checkType(short datatype, const char* name)
{
    const Dir dir(name);
    for (bool big : {false, true})
        for (int scaled = 0; scaled < 2; ++scaled)
            for (bool gz : {false, true}) {
                Layout l;
                l.bigEndian = big;
                if (scaled) {  // inexact in binary: float and double arithmetic round differently
                    l.slope = 0.37f;
                    l.inter = -1024.3f;
                }
                const std::string file = std::string(name) + (big ? "_be" : "_le") + (scaled ? "_scaled" : "") +
                                         (gz ? ".nii.gz" : ".nii");
                const fs::path p = dir.path / file;
                const auto bytes = niftiBytes<T>(datatype, l);
                if (gz) writeGzip(p, bytes);
                else writePlain(p, bytes);
                // Scaled doubles are left to ITK (it scales them in double).
                SCOPED_TRACE(file);
                expectSameAsItk(p, !(scaled && std::is_same_v<T, double>));
            }
}

} // namespace

TEST(Nifti1Voxels, EveryTypeByteOrderScalingAndGzipReadsExactlyAsItk)
{
    checkType<uint8_t>(DT_UINT8, "uint8");
    checkType<int8_t>(DT_INT8, "int8");
    checkType<int16_t>(DT_INT16, "int16");
    checkType<uint16_t>(DT_UINT16, "uint16");
    checkType<int32_t>(DT_INT32, "int32");
    checkType<uint32_t>(DT_UINT32, "uint32");
    checkType<int64_t>(DT_INT64, "int64");
    checkType<float>(DT_FLOAT32, "float32");
    checkType<double>(DT_FLOAT64, "float64");
}

TEST(Nifti1Voxels, AGzipStreamEndingEarlyIsRefusedNamingTheFile)
{
    const Dir dir("short");
    Layout l;
    auto bytes = niftiBytes<int16_t>(DT_INT16, l);
    bytes.resize(bytes.size() - 2 * std::size_t(l.nx * l.ny) - 10);  // a clean gzip stream of a cut file
    const fs::path p = dir.path / "short.nii.gz";
    writeGzip(p, bytes);
    std::string message;
    try {
        auto source = openImage(p.string());
        std::vector<float> all(std::size_t(l.nx * l.ny * l.nz));
        source->readSlices(0, l.nz, all.data());
    } catch (const InputError& e) {
        message = e.what();
    }
    EXPECT_NE(message.find("short.nii.gz: header/data size mismatch"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
}

TEST(Nifti1Voxels, ClosingASourceWhileItsReaderIsAheadNeitherHangsNorLeaks)
{
    // 256 x 256 x 160 int16: the reading thread runs up to a few blocks ahead and then waits;
    // closing the source must stop it. Reading forward, backwards and forward again gives the
    // same values.
    const Dir dir("ahead");
    Layout l;
    l.nx = 256;
    l.ny = 256;
    l.nz = 160;
    const fs::path p = dir.path / "ahead.nii.gz";
    writeGzip(p, niftiBytes<int16_t>(DT_INT16, l));
    const std::size_t perSlice = std::size_t(l.nx * l.ny);
    std::vector<float> a(perSlice * 2), b(perSlice * 2);
    for (int round = 0; round < 3; ++round) {
        auto source = openImage(p.string());
        EXPECT_EQ(source->heldBytes(), 0);
        source->readSlices(150, 152, a.data());
        source->readSlices(3, 5, b.data());
        EXPECT_EQ(b[0], float(pattern<int16_t>(0, 0, 3)));
        EXPECT_EQ(a[perSlice + 5], float(pattern<int16_t>(5, 0, 151)));
        source->readSlices(0, 1, b.data());  // and close with the reader running ahead
        EXPECT_EQ(b[l.nx + 1], float(pattern<int16_t>(1, 1, 0)));
    }
}

namespace {

/// One gzip member of `n` bytes, deflated by zlib at `level` (0: stored blocks by zlib).
std::string gzipMember(const char* data, std::size_t n, int level)
{
    z_stream z{};
    EXPECT_EQ(::deflateInit2(&z, level, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY), Z_OK);
    std::string out(::deflateBound(&z, uLong(n)) + 64, '\0');
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data));
    z.avail_in = uInt(n);
    z.next_out = reinterpret_cast<Bytef*>(out.data());
    z.avail_out = uInt(out.size());
    EXPECT_EQ(::deflate(&z, Z_FINISH), Z_STREAM_END);
    out.resize(z.total_out);
    ::deflateEnd(&z);
    return out;
}

/// One gzip member of stored (uncompressed) deflate blocks, written byte by byte, so that its
/// length is known exactly: 10 + 5 per block of up to 65535 bytes + n + 8.
std::string storedMember(const char* data, std::size_t n)
{
    std::string out("\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03", 10);
    std::size_t at = 0;
    do {
        const std::size_t len = std::min<std::size_t>(n - at, 65535);
        const bool last = at + len == n;
        out += char(last ? 1 : 0);
        out += char(len & 0xff);
        out += char(len >> 8);
        out += char(~len & 0xff);
        out += char((~len >> 8) & 0xff);
        out.append(data + at, len);
        at += len;
    } while (at < n);
    const uint32_t crc = uint32_t(::crc32(0, reinterpret_cast<const Bytef*>(data), uInt(n)));
    const uint32_t size = uint32_t(n);
    for (uint32_t v : {crc, size})
        for (int b = 0; b < 4; ++b) out += char((v >> (8 * b)) & 0xff);
    return out;
}

/// A 256 x 256 x 24 int16 .nii of noise (gzip shrinks it little: its members are megabytes).
std::vector<char> noisyNifti(Layout& l)
{
    l.nx = 256;
    l.ny = 256;
    l.nz = 24;
    auto bytes = niftiBytes<int16_t>(DT_INT16, l);
    uint32_t state = 12345;
    for (std::size_t at = 352; at + 1 < bytes.size(); at += 2) {
        state = state * 1664525u + 1013904223u;
        const int16_t v = int16_t(int(state >> 20) - 2048);
        std::memcpy(bytes.data() + at, &v, 2);
    }
    return bytes;
}

/// What openImage and reading every slice of `p` throw ("" when nothing).
std::string readError(const fs::path& p, const Layout& l)
{
    try {
        auto source = openImage(p.string());
        std::vector<float> all(std::size_t(l.nx) * std::size_t(l.ny) * std::size_t(l.nz));
        source->readSlices(0, l.nz, all.data());
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

void writeBytes(const fs::path& p, const std::string& bytes)
{
    std::ofstream(p, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
}

} // namespace

TEST(Nifti1Voxels, GzipMembersTrailingBytesAndUncompressedBytesReadExactlyAsItk)
{
    // What zlib's gzread (and so ITK) reads: concatenated members one after the other, bytes
    // after the last member that do not start another ignored, a .nii.gz that is not gzipped
    // as it is. The first member is stored blocks of exactly 1 MiB - 1 bytes, so that the next
    // member's two magic bytes straddle a 1 MiB boundary of the compressed file; then an empty
    // member, a one-byte member, members deflated at levels 6 and 1.
    const Dir dir("members");
    Layout l;
    const auto raw = noisyNifti(l);
    const std::size_t a = 1048477;  // 18 + 5 * 16 blocks + a = 1 MiB - 1
    const std::size_t b = a + 700001, c = b + 1;
    ASSERT_LT(c, raw.size());
    std::string members = storedMember(raw.data(), a);
    ASSERT_EQ(members.size(), (std::size_t(1) << 20) - 1);
    members += gzipMember(raw.data() + a, b - a, 6);
    members += gzipMember(raw.data(), 0, 6);
    members += storedMember(raw.data() + b, 1);
    members += gzipMember(raw.data() + c, raw.size() - c, 1);
    writeBytes(dir.path / "members.nii.gz", members);
    expectSameAsItk(dir.path / "members.nii.gz", true);

    writeBytes(dir.path / "trailing.nii.gz", gzipMember(raw.data(), raw.size(), 6) + std::string("\0\0not gzip", 10));
    expectSameAsItk(dir.path / "trailing.nii.gz", true);

    writePlain(dir.path / "plain.nii.gz", raw);
    expectSameAsItk(dir.path / "plain.nii.gz", true);
}

TEST(Nifti1Voxels, CorruptOrCutGzipDataIsRefusedInOneLineNamingTheFile)
{
    const Dir dir("corrupt");
    Layout l;
    const auto raw = noisyNifti(l);
    const std::string good = gzipMember(raw.data(), raw.size(), 6);
    const std::size_t half = raw.size() / 2;
    const std::string first = gzipMember(raw.data(), half, 6);
    const std::string two = first + gzipMember(raw.data() + half, raw.size() - half, 6);
    struct Case {
        std::string name, bytes, expect;
    };
    std::vector<Case> cases;
    auto flipped = [](std::string s, std::size_t at) {
        s[at] = char(s[at] ^ 0x55);
        return s;
    };
    cases.push_back({"crc.nii.gz", flipped(good, good.size() - 6), "(incorrect data check"});
    cases.push_back({"isize.nii.gz", flipped(good, good.size() - 2), "(incorrect data check"});
    cases.push_back({"first_crc.nii.gz", flipped(two, first.size() - 6), "(incorrect data check"});
    cases.push_back({"deflate.nii.gz", flipped(flipped(good, good.size() / 2), good.size() / 2 + 7),
                     "gzip data is truncated or corrupt after"});
    cases.push_back({"cut.nii.gz", good.substr(0, good.size() * 3 / 4), "(unexpected end of file)"});
    cases.push_back({"cut_trailer.nii.gz", good.substr(0, good.size() - 3), "gzip data is truncated or corrupt after"});
    cases.push_back({"cut_member.nii.gz", two.substr(0, first.size() + 5), "gzip data is truncated or corrupt after"});
    // Scaled double voxels go through ITK's reader, from a copy inflated to a temporary file
    // (volume/io/gunzip.h): the same checks there.
    Layout scaled;  // larger than the 8 KB zlib takes in to read the header
    scaled.nx = 64;
    scaled.ny = 64;
    scaled.nz = 20;
    scaled.slope = 0.37f;
    scaled.inter = -1024.3f;
    const auto doubles = niftiBytes<double>(DT_FLOAT64, scaled);
    const std::string whole = gzipMember(doubles.data(), doubles.size(), 6);
    cases.push_back({"itk_cut.nii.gz", whole.substr(0, whole.size() / 2), "(unexpected end of file)"});
    cases.push_back({"itk_crc.nii.gz", flipped(whole, whole.size() - 6), "(incorrect data check"});
    for (const Case& c : cases) {
        const fs::path p = dir.path / c.name;
        writeBytes(p, c.bytes);
        const std::string message = readError(p, c.name.rfind("itk_", 0) == 0 ? scaled : l);
        EXPECT_NE(message.find(p.string() + ": "), std::string::npos)
            << c.name << ": expected the file named, got \"" << message << "\"";
        EXPECT_NE(message.find(c.expect), std::string::npos)
            << c.name << ": expected \"" << c.expect << "\", got \"" << message << "\"";
        EXPECT_EQ(message.find('\n'), std::string::npos) << c.name << ": one line: " << message;
    }
}
