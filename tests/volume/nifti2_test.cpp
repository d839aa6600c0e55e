// NIfTI-2: flyover reads its header itself (ITK 5.2 reads NIfTI-1 only), so every way a
// header can place the voxels is checked against ITK reading the same fields as NIfTI-1:
// sform only, qform only, both agreeing, both disagreeing with each sform code, neither,
// qfac -1, sform with shear, metre and micron units. (One deviation from ITK 5.2, made on
// both paths: ITK scales metre/micron spacing to mm but not the offsets; flyover scales both.) Also big-endian, gzip, scl_slope and
// the voxel values.

#include "tests/volume/image_fixtures.h"

#include "volume/error.h"
#include "volume/image_io.h"

#include <nifti/nifti1.h>
#include <nifti/nifti2.h>

#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

constexpr int NX = 5, NY = 4, NZ = 3;

/// The fields both headers carry, NIfTI-1 meaning.
struct Fields {
    int qformCode = 0, sformCode = 0;
    double quat[3] = {0, 0, 0}, qoffset[3] = {0, 0, 0};
    double pixdim[4] = {1, 0.8, 0.9, 1.25};  // [0] = qfac
    double srow[3][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}, {0, 0, 0, 0}};
    int units = 2;  // mm
    double slope = 0, inter = 0;
};

std::vector<int16_t> voxels()
{
    std::vector<int16_t> v(NX * NY * NZ);
    for (int k = 0; k < NZ; ++k)
        for (int j = 0; j < NY; ++j)
            for (int i = 0; i < NX; ++i) v[std::size_t(i + NX * (j + NY * k))] = int16_t(i + 10 * j + 100 * k - 200);
    return v;
}

void writeBytes(const fs::path& p, const std::vector<char>& bytes)
{
    std::ofstream(p, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
}

std::vector<char> withVoxels(const void* header, std::size_t headerBytes, std::size_t offset)
{
    const auto v = voxels();
    std::vector<char> bytes(offset + v.size() * 2, 0);
    std::memcpy(bytes.data(), header, headerBytes);
    std::memcpy(bytes.data() + offset, v.data(), v.size() * 2);
    return bytes;
}

std::vector<char> nifti1(const Fields& f)
{
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    std::memcpy(h.magic, "n+1\0", 4);
    h.datatype = DT_INT16;
    h.bitpix = 16;
    const short dims[8] = {3, NX, NY, NZ, 1, 1, 1, 1};
    std::memcpy(h.dim, dims, sizeof dims);
    for (int c = 0; c < 4; ++c) h.pixdim[c] = float(f.pixdim[c]);
    h.vox_offset = 352;
    h.scl_slope = float(f.slope);
    h.scl_inter = float(f.inter);
    h.qform_code = short(f.qformCode);
    h.sform_code = short(f.sformCode);
    h.quatern_b = float(f.quat[0]);
    h.quatern_c = float(f.quat[1]);
    h.quatern_d = float(f.quat[2]);
    h.qoffset_x = float(f.qoffset[0]);
    h.qoffset_y = float(f.qoffset[1]);
    h.qoffset_z = float(f.qoffset[2]);
    for (int c = 0; c < 4; ++c) {
        h.srow_x[c] = float(f.srow[0][c]);
        h.srow_y[c] = float(f.srow[1][c]);
        h.srow_z[c] = float(f.srow[2][c]);
    }
    h.xyzt_units = char(f.units);
    return withVoxels(&h, sizeof h, 352);
}

nifti_2_header nifti2Header(const Fields& f)
{
    nifti_2_header h{};
    h.sizeof_hdr = 540;
    std::memcpy(h.magic, "n+2\0\r\n\032\n", 8);
    h.datatype = DT_INT16;
    h.bitpix = 16;
    const int64_t dims[8] = {3, NX, NY, NZ, 1, 1, 1, 1};
    std::memcpy(h.dim, dims, sizeof dims);
    // Through float, as NIfTI-1 stores them, so both files describe the very same numbers.
    for (int c = 0; c < 4; ++c) h.pixdim[c] = double(float(f.pixdim[c]));
    h.vox_offset = 544;
    h.scl_slope = double(float(f.slope));
    h.scl_inter = double(float(f.inter));
    h.qform_code = f.qformCode;
    h.sform_code = f.sformCode;
    h.quatern_b = double(float(f.quat[0]));
    h.quatern_c = double(float(f.quat[1]));
    h.quatern_d = double(float(f.quat[2]));
    h.qoffset_x = double(float(f.qoffset[0]));
    h.qoffset_y = double(float(f.qoffset[1]));
    h.qoffset_z = double(float(f.qoffset[2]));
    for (int c = 0; c < 4; ++c) {
        h.srow_x[c] = double(float(f.srow[0][c]));
        h.srow_y[c] = double(float(f.srow[1][c]));
        h.srow_z[c] = double(float(f.srow[2][c]));
    }
    h.xyzt_units = f.units;
    return h;
}

std::vector<char> nifti2(const Fields& f) { const auto h = nifti2Header(f); return withVoxels(&h, sizeof h, 544); }

template <typename T>
void swapped(T& v)
{
    auto* b = reinterpret_cast<unsigned char*>(&v);
    std::reverse(b, b + sizeof(T));
}

/// The same file in big-endian byte order.
std::vector<char> nifti2BigEndian(const Fields& f)
{
    nifti_2_header h = nifti2Header(f);
    swapped(h.sizeof_hdr);
    swapped(h.datatype);
    swapped(h.bitpix);
    for (auto& v : h.dim) swapped(v);
    for (auto& v : h.pixdim) swapped(v);
    swapped(h.vox_offset);
    swapped(h.scl_slope);
    swapped(h.scl_inter);
    swapped(h.qform_code);
    swapped(h.sform_code);
    for (double* v : {&h.quatern_b, &h.quatern_c, &h.quatern_d, &h.qoffset_x, &h.qoffset_y, &h.qoffset_z}) swapped(*v);
    for (int c = 0; c < 4; ++c) {
        swapped(h.srow_x[c]);
        swapped(h.srow_y[c]);
        swapped(h.srow_z[c]);
    }
    swapped(h.xyzt_units);
    auto v = voxels();
    for (auto& x : v) swapped(x);
    std::vector<char> bytes(544 + v.size() * 2, 0);
    std::memcpy(bytes.data(), &h, sizeof h);
    std::memcpy(bytes.data() + 544, v.data(), v.size() * 2);
    return bytes;
}

/// A rotation (columns orthonormal) from a unit quaternion (a, b, c, d), as NIfTI defines it.
void rotationFromQuaternion(double b, double c, double d, double R[3][3])
{
    const double a = std::sqrt(std::max(0.0, 1 - b * b - c * c - d * d));
    const double m[3][3] = {{a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)},
                            {2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b)},
                            {2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - c * c - b * b}};
    std::memcpy(R, m, sizeof m);
}

/// An sform of rotation R (third column times qfac), spacing pixdim and translation t.
void setSform(Fields& f, const double R[3][3], double qfac, const double t[3])
{
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) f.srow[r][c] = R[r][c] * f.pixdim[c + 1] * (c == 2 ? qfac : 1.0);
        f.srow[r][3] = t[r];
    }
}

struct Scratch {
    fs::path dir = fs::temp_directory_path() / ("flyover-nifti2-" + std::to_string(::getpid()));
    Scratch() { fs::create_directories(dir); }
    ~Scratch() { fs::remove_all(dir); }
};

std::string errorOf(const std::string& path)
{
    try {
        readImage(path);
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

void expectSameImage(const Image3<float>& a, const Image3<float>& b, const std::string& what)
{
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(a.geometry.size[c], b.geometry.size[c]) << what;
        EXPECT_NEAR(a.geometry.spacingMm[c], b.geometry.spacingMm[c], 1e-5) << what << " spacing " << c;
        EXPECT_NEAR(a.geometry.originMm[c], b.geometry.originMm[c], 1e-4) << what << " origin " << c;
        for (int r = 0; r < 3; ++r)
            EXPECT_NEAR(a.geometry.direction[r][c], b.geometry.direction[r][c], 1e-5) << what << " direction[" << r << "][" << c << "]";
    }
    ASSERT_EQ(a.voxels.size(), b.voxels.size()) << what;
    EXPECT_TRUE(a.voxels == b.voxels) << what << ": voxel values differ";
}

} // namespace

TEST(Nifti2, EveryWayOfPlacingVoxelsAgreesWithItkReadingTheSameFieldsAsNifti1)
{
    Scratch s;
    // A rotation about (1, 2, 3) by 40 degrees, and another about (0, 1, 0) by 25 degrees.
    const double pi = 3.14159265358979323846;
    auto quat = [&](double ax, double ay, double az, double deg, double q[3]) {
        const double n = std::sqrt(ax * ax + ay * ay + az * az), h = std::sin(deg * pi / 360) / n;
        q[0] = ax * h;
        q[1] = ay * h;
        q[2] = az * h;
    };
    double q1[3], q2[3], R1[3][3], R2[3][3];
    quat(1, 2, 3, 40, q1);
    quat(0, 1, 0, 25, q2);
    rotationFromQuaternion(q1[0], q1[1], q1[2], R1);
    rotationFromQuaternion(q2[0], q2[1], q2[2], R2);
    const double t1[3] = {-31.5, 12.25, 80.0}, t2[3] = {4.0, -7.5, -3.0};

    struct Case { std::string name; Fields f; };
    std::vector<Case> cases;
    {
        Fields f;  // sform only (scanner)
        f.sformCode = 1;
        setSform(f, R1, 1, t1);
        cases.push_back({"sform_only", f});
    }
    {
        Fields f;  // qform only, qfac -1 (a left-handed index frame)
        f.qformCode = 1;
        f.pixdim[0] = -1;
        std::copy(q1, q1 + 3, f.quat);
        std::copy(t1, t1 + 3, f.qoffset);
        cases.push_back({"qform_only_qfac-1", f});
    }
    {
        Fields f;  // both, agreeing
        f.qformCode = 1;
        f.sformCode = 1;
        std::copy(q1, q1 + 3, f.quat);
        std::copy(t1, t1 + 3, f.qoffset);
        setSform(f, R1, 1, t1);
        cases.push_back({"both_agree", f});
    }
    for (int sformCode : {1, 2, 3, 4}) {
        Fields f;  // both, disagreeing
        f.qformCode = 1;
        f.sformCode = sformCode;
        std::copy(q1, q1 + 3, f.quat);
        std::copy(t1, t1 + 3, f.qoffset);
        setSform(f, R2, 1, t2);
        cases.push_back({"both_disagree_sform_code_" + std::to_string(sformCode), f});
    }
    {
        Fields f;  // neither
        cases.push_back({"neither", f});
    }
    {
        Fields f;  // sform with shear next to a qform
        f.qformCode = 1;
        f.sformCode = 1;
        std::copy(q2, q2 + 3, f.quat);
        std::copy(t2, t2 + 3, f.qoffset);
        setSform(f, R1, 1, t1);
        f.srow[0][1] += 0.3;
        cases.push_back({"sheared_sform_with_qform", f});
    }
    for (int units : {1, 3}) {
        Fields f;  // metres, microns (qform)
        f.qformCode = 1;
        f.units = units;
        f.pixdim[1] = units == 1 ? 0.0008 : 800;
        f.pixdim[2] = units == 1 ? 0.0009 : 900;
        f.pixdim[3] = units == 1 ? 0.00125 : 1250;
        std::copy(q1, q1 + 3, f.quat);
        const double scale = units == 1 ? 0.001 : 1000;
        for (int c = 0; c < 3; ++c) f.qoffset[c] = t1[c] * scale;
        cases.push_back({units == 1 ? "metres" : "microns", f});
    }
    {
        Fields f;  // scl_slope / scl_inter
        f.qformCode = 1;
        std::copy(q2, q2 + 3, f.quat);
        f.slope = 0.5;
        f.inter = -1024;
        cases.push_back({"scaled", f});
    }

    for (const Case& c : cases) {
        const fs::path p1 = s.dir / (c.name + ".nii"), p2 = s.dir / (c.name + "_2.nii");
        writeBytes(p1, nifti1(c.f));
        writeBytes(p2, nifti2(c.f));
        const std::string e1 = errorOf(p1.string()), e2 = errorOf(p2.string());
        ASSERT_EQ(e1.empty(), e2.empty()) << c.name << ": ITK (NIfTI-1) says \"" << e1 << "\", flyover (NIfTI-2) says \"" << e2 << "\"";
        if (!e1.empty()) continue;
        const Image3<float> img2 = readImage(p2.string());
        expectSameImage(img2, readImage(p1.string()), c.name);
        if (c.name == "metres" || c.name == "microns") {  // offsets are scaled to mm like pixdim
            for (int r = 0; r < 3; ++r) EXPECT_NEAR(img2.geometry.originMm[r], (r < 2 ? -1 : 1) * t1[r], 1e-3) << c.name;
        }
    }
}

TEST(Nifti2, BigEndianGzipAndHdrImgPairReadAsTheLittleEndianFile)
{
    Scratch s;
    Fields f;
    f.qformCode = 1;
    f.sformCode = 1;
    const double q[3] = {0.1, -0.2, 0.3}, t[3] = {10, 20, 30};
    std::copy(q, q + 3, f.quat);
    std::copy(t, t + 3, f.qoffset);
    double R[3][3];
    rotationFromQuaternion(q[0], q[1], q[2], R);
    setSform(f, R, 1, t);
    const fs::path le = s.dir / "le.nii", be = s.dir / "be.nii", gz = s.dir / "le.nii.gz";
    writeBytes(le, nifti2(f));
    writeBytes(be, nifti2BigEndian(f));
    {
        const auto bytes = nifti2(f);
        gzFile out = ::gzopen(gz.c_str(), "wb");
        ASSERT_NE(out, nullptr);
        ::gzwrite(out, bytes.data(), unsigned(bytes.size()));
        ::gzclose(out);
    }
    {  // a .hdr/.img pair ("ni2" magic, voxels from byte 0 of the .img)
        nifti_2_header h = nifti2Header(f);
        std::memcpy(h.magic, "ni2\0\r\n\032\n", 8);
        h.vox_offset = 0;
        writeBytes(s.dir / "pair.hdr", std::vector<char>(reinterpret_cast<char*>(&h), reinterpret_cast<char*>(&h) + sizeof h));
        const auto bytes = nifti2(f);
        writeBytes(s.dir / "pair.img", std::vector<char>(bytes.begin() + 544, bytes.end()));
    }
    const Image3<float> reference = readImage(le.string());
    expectSameImage(readImage((s.dir / "pair.hdr").string()), reference, "hdr/img pair");
    expectSameImage(readImage(be.string()), reference, "big-endian");
    expectSameImage(readImage(gz.string()), reference, "gzip");
    EXPECT_EQ(reference.at(4, 3, 2), 4 + 30 + 200 - 200);
    EXPECT_NE(openImage(gz.string())->description().find("NIfTI-2"), std::string::npos);
    EXPECT_EQ(openImage(le.string())->heldBytes(), 0) << "streamed by slab";
}

TEST(Nifti2, TheFixtureMatchesTheSameVolumeAsNifti1)
{
    expectSameImage(readImage(fixture("same_nifti2.nii")), readImage(fixture("same.nii")), "same_nifti2.nii");
}

TEST(Nifti2, BadHeadersGiveOneLineNamingTheFile)
{
    Scratch s;
    Fields f;
    f.qformCode = 1;
    struct Case { std::string name; std::string expect; std::function<void(nifti_2_header&)> edit; std::size_t keep; };
    const std::vector<Case> cases{
        {"time_series", "a single 3D volume is needed", [](nifti_2_header& h) { h.dim[0] = 4; h.dim[4] = 3; }, 0},
        {"two_d", "image is 2D", [](nifti_2_header& h) { h.dim[3] = 1; }, 0},
        {"bad_dim0", "dim[0] is 9", [](nifti_2_header& h) { h.dim[0] = 9; }, 0},
        {"negative_dim", "dim[2] is -4", [](nifti_2_header& h) { h.dim[2] = -4; }, 0},
        {"bitpix", "bitpix 8 does not match datatype 4", [](nifti_2_header& h) { h.bitpix = 8; }, 0},
        {"rgb", "voxel type RGB24 is not supported", [](nifti_2_header& h) { h.datatype = 128; h.bitpix = 24; }, 0},
        {"zero_spacing", "voxel spacing along j (y) is 0 mm", [](nifti_2_header& h) { h.pixdim[2] = 0; }, 0},
        {"nan_spacing", "voxel spacing along k (z) is nan mm", [](nifti_2_header& h) { h.pixdim[3] = NAN; }, 0},
        {"offset_in_header", "vox_offset 100 lies inside the header", [](nifti_2_header& h) { h.vox_offset = 100; }, 0},
        {"huge", "header/data size mismatch", [](nifti_2_header& h) { h.dim[1] = h.dim[2] = h.dim[3] = 100000; }, 0},
        // The product overflows int64 (found by fuzzing: UBSan in ImageGeometry::voxelCount).
        {"overflow", "more than any file holds", [](nifti_2_header& h) { h.dim[1] = h.dim[2] = h.dim[3] = int64_t(1) << 31; }, 0},
        {"magic", "no valid magic", [](nifti_2_header& h) { std::memcpy(h.magic, "xyz\0", 4); }, 0},
        {"short_header", "NIfTI-2 header is truncated (300 of 540 bytes)", [](nifti_2_header&) {}, 300},
        {"sheared_no_qform", "sform has shear", [](nifti_2_header& h) {
             h.qform_code = 0; h.sform_code = 1;
             h.srow_x[0] = 0.8; h.srow_y[1] = 0.9; h.srow_z[2] = 1.25; h.srow_x[1] = 0.4; }, 0},
        {"nan_inter", "scl_slope or scl_inter is not finite", [](nifti_2_header& h) { h.scl_slope = 1; h.scl_inter = NAN; }, 0},
    };
    for (const Case& c : cases) {
        nifti_2_header h = nifti2Header(f);
        c.edit(h);
        auto bytes = withVoxels(&h, sizeof h, 544);
        if (c.keep) bytes.resize(c.keep);
        const fs::path p = s.dir / (c.name + ".nii");
        writeBytes(p, bytes);
        const std::string msg = errorOf(p.string());
        EXPECT_NE(msg.find(c.expect), std::string::npos) << c.name << ": expected \"" << c.expect << "\", got \"" << msg << "\"";
        EXPECT_EQ(msg.rfind(p.string(), 0), 0u) << c.name << ": the message starts with the file: " << msg;
        EXPECT_EQ(msg.find('\n'), std::string::npos) << c.name << ": one line";
    }
}
