// Reading scans: the same volume in every format, DICOM ordering, series choice and
// compressed transfer syntaxes, the real CT's geometry against its headers, and one clear
// InputError naming the file for every kind of bad input.

#include "tests/volume/image_fixtures.h"

#include "volume/error.h"
#include "volume/image_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

const std::vector<std::string>& sameVolumeFixtures()
{
    static const std::vector<std::string> names{
        "same.nii.gz", "same.nii",     "same_scaled.nii", "same.nrrd",       "same.nhdr",        "same.mha",
        "same_zlib.mha", "same.mhd",   "same_nifti2.nii", "dicom/same",      "dicom/same_j2k",  "dicom/same_jpegll"};
    return names;
}

/// Tolerance of world positions: NIfTI stores direction and origin as float32.
constexpr double WORLD_TOL_MM = 1e-4;

void expectGeometryNear(const ImageGeometry& g, const ImageGeometry& want, const std::string& what)
{
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(g.size[c], want.size[c]) << what << " axis " << c;
        EXPECT_NEAR(g.spacingMm[c], want.spacingMm[c], 1e-6) << what << " axis " << c;
        EXPECT_NEAR(g.originMm[c], want.originMm[c], WORLD_TOL_MM) << what << " axis " << c;
        for (int r = 0; r < 3; ++r) EXPECT_NEAR(g.direction[r][c], want.direction[r][c], 1e-6) << what << " [" << r << "][" << c << "]";
    }
}

/// InputError's message, or "" when none was thrown.
std::string openError(const std::string& path, const ImageReadOptions& options = {})
{
    try {
        auto source = openImage(path, options);
        std::vector<float> buf(static_cast<std::size_t>(source->geometry().voxelCount()));
        source->readSlices(0, source->geometry().size[2], buf.data());
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

struct TempDir {
    fs::path path;
    explicit TempDir(const std::string& tag)
        : path(fs::temp_directory_path() / ("flyover-imageio-" + tag + "-" + std::to_string(::getpid())))
    {
        fs::remove_all(path);
        fs::create_directories(path);
    }
    ~TempDir() { fs::remove_all(path); }
};

} // namespace

TEST(ImageIo, SameVolumeInEveryFormatHasTheWrittenGeometry)
{
    for (const auto& name : sameVolumeFixtures()) {
        auto source = openImage(fixture(name));
        expectGeometryNear(source->geometry(), fixtureGeometry(), name);
        EXPECT_TRUE(source->isRegular()) << name;
        EXPECT_TRUE(source->warnings().empty()) << name << ": " << source->warnings().front();
    }
}

TEST(ImageIo, SameVolumeInEveryFormatHasIdenticalVoxels)
{
    const Image3<float> reference = readImage(fixture("same.nii"));
    for (const auto& name : sameVolumeFixtures()) {
        const Image3<float> img = readImage(fixture(name));
        ASSERT_EQ(img.voxels.size(), reference.voxels.size()) << name;
        std::size_t differing = 0;
        for (std::size_t n = 0; n < img.voxels.size(); ++n) differing += img.voxels[n] != reference.voxels[n];
        EXPECT_EQ(differing, 0u) << name << " (DICOM: stored HU + 1024 with Rescale Intercept -1024)";
    }
}

TEST(ImageIo, VoxelIndexMapsToTheWorldPositionItWasWrittenAt)
{
    // Inside the body each voxel holds round(f(world position)) for a linear f: reading it
    // back at worldFromIndex(i,j,k) checks index -> LPS mm end to end, per format.
    for (const auto& name : sameVolumeFixtures()) {
        const Image3<float> img = readImage(fixture(name));
        int checked = 0;
        for (int64_t k = 0; k < FX_NZ; ++k)
            for (int64_t j = 0; j < FX_NY; ++j)
                for (int64_t i = 0; i < FX_NX; ++i) {
                    if (!insideFixtureBody(double(i), double(j)) || insideFixturePocket(i, j, k)) continue;
                    const Vec3d p = img.geometry.worldFromIndex({double(i), double(j), double(k)});
                    ASSERT_EQ(img.at(i, j, k), std::round(fixtureBodyHu(p))) << name << " voxel " << i << "," << j << "," << k;
                    ++checked;
                }
        EXPECT_GT(checked, 1000) << name;  // about pi * 7 * 5 voxels per slice, 10 slices
    }
}

TEST(ImageIo, StreamsWhatCanBeReadByRegionAndNeverHoldsFloat)
{
    struct Case { const char* name; bool streamed; };
    for (const Case& c : {Case{"same.nii", true}, Case{"same.nii.gz", true}, Case{"same.mha", true}, Case{"same.mhd", true},
                          Case{"same_nifti2.nii", true}, Case{"dicom/same", true}, Case{"same.nrrd", false}, Case{"same_zlib.mha", false}}) {
        auto source = openImage(fixture(c.name));
        const int64_t native = FX_NX * FX_NY * FX_NZ * 2;  // int16
        EXPECT_EQ(source->heldBytes(), c.streamed ? 0 : native) << c.name << ": " << source->description();
    }
    EXPECT_NE(openImage(fixture("same.nii.gz"))->description().find("inflated by ISA-L while streamed"), std::string::npos);
    EXPECT_NE(openImage(fixture("dicom/same"))->description().find("file by file"), std::string::npos);
}

TEST(ImageIo, ReadsSlabsInAnyOrderWithTheSameValues)
{
    for (const char* name : {"same.nii", "same.nii.gz", "same.mha", "same.nrrd", "same_nifti2.nii", "dicom/same_j2k"}) {
        const Image3<float> whole = readImage(fixture(name));
        auto source = openImage(fixture(name));
        const std::size_t perSlice = FX_NX * FX_NY;
        std::vector<float> slab(perSlice * 3);
        for (int64_t k0 : {7, 0, 4}) {
            source->readSlices(k0, k0 + 3, slab.data());
            for (std::size_t n = 0; n < slab.size(); ++n)
                ASSERT_EQ(slab[n], whole.voxels[perSlice * std::size_t(k0) + n]) << name << " slab at " << k0;
        }
    }
}

TEST(ImageIo, DicomSliceOrderComesFromPositionsNotNamesOrInstanceNumbers)
{
    // The fixture's file names and Instance Numbers both run against the slice positions.
    auto source = openImage(fixture("dicom/same"));
    const auto& origins = source->sliceOriginsMm();
    ASSERT_EQ(origins.size(), std::size_t(FX_NZ));
    const ImageGeometry want = fixtureGeometry();
    for (int64_t k = 0; k < FX_NZ; ++k) {
        const Vec3d p = want.worldFromIndex({0, 0, double(k)});
        EXPECT_NEAR(distance(origins[std::size_t(k)], p), 0.0, WORLD_TOL_MM) << "slice " << k;
    }
}

TEST(ImageIo, DicomFolderWithTwoSeriesReadsTheLargestOrTheOneAsked)
{
    auto largest = openImage(fixture("dicom/two_series"));
    EXPECT_EQ(largest->geometry().size[2], 6);
    ASSERT_EQ(largest->warnings().size(), 1u);
    EXPECT_NE(largest->warnings()[0].find("holds 2 series"), std::string::npos) << largest->warnings()[0];

    ImageReadOptions options;
    options.dicomSeriesUid = "1.2.826.0.1.3680043.2.1125.77.2.41";
    auto asked = openImage(fixture("dicom/two_series"), options);
    EXPECT_EQ(asked->geometry().size[2], 4);
    EXPECT_TRUE(asked->warnings().empty());

    options.dicomSeriesUid = "1.2.3.4";
    const std::string msg = openError(fixture("dicom/two_series"), options);
    EXPECT_NE(msg.find("no DICOM series 1.2.3.4"), std::string::npos) << msg;
    EXPECT_NE(msg.find("77.2.41 (4 files)"), std::string::npos) << msg;
}

TEST(ImageIo, RealDicomSlicesMatchTheirHeaders)
{
    // Values from gdcmdump of the three committed slices (JPEG 2000 lossless, 1.2.840.10008.1.2.4.90):
    // Image Position (Patient) -249.51171875\-437.51171875\{-766.5,-768.5,-770.5},
    // Image Orientation (Patient) 1\0\0\0\1\0, Pixel Spacing 0.9765625\0.9765625,
    // Rows = Columns = 512, Rescale Intercept -1024, Slope 1, stored 12-bit unsigned.
    auto source = openImage(fixture("real/dicom"));
    const ImageGeometry& g = source->geometry();
    EXPECT_EQ(g.size, (std::array<int64_t, 3>{512, 512, 3}));
    EXPECT_DOUBLE_EQ(g.spacingMm.x, 0.9765625);
    EXPECT_DOUBLE_EQ(g.spacingMm.y, 0.9765625);
    EXPECT_DOUBLE_EQ(g.spacingMm.z, 2.0);
    EXPECT_DOUBLE_EQ(g.originMm.x, -249.51171875);
    EXPECT_DOUBLE_EQ(g.originMm.y, -437.51171875);
    EXPECT_DOUBLE_EQ(g.originMm.z, -770.5);  // the lowest slice along the normal (0,0,1)
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(g.direction[r][c], r == c ? 1.0 : 0.0);
    EXPECT_TRUE(source->isRegular());

    const Image3<float> img = readImage(fixture("real/dicom"));
    const auto mm = std::minmax_element(img.voxels.begin(), img.voxels.end());
    EXPECT_EQ(*mm.first, -1024.0f) << "stored 0 + Rescale Intercept -1024: the rescale was applied";
    EXPECT_GT(*mm.second, 1000.0f) << "bone";
    EXPECT_EQ(img.at(0, 0, 0), -1024.0f);
    EXPECT_NEAR(img.at(256, 256, 0), 0.0, 150.0) << "soft tissue at the centre of the abdomen";
}

TEST(ImageIo, AllTwentyRealDicomSlicesWhenTheSharedDataIsThere)
{
    const std::string dir = sharedReal("example_ct_dicom");
    if (!fs::exists(dir)) GTEST_SKIP() << dir << " is not in this checkout";
    auto source = openImage(dir);
    const ImageGeometry& g = source->geometry();
    EXPECT_EQ(g.size, (std::array<int64_t, 3>{512, 512, 20}));
    EXPECT_DOUBLE_EQ(g.spacingMm.z, 2.0);  // positions 2 mm apart; Slice Thickness 3 mm is not the step
    EXPECT_DOUBLE_EQ(g.originMm.z, -804.5);
    EXPECT_DOUBLE_EQ(g.originMm.x, -249.51171875);
    const Image3<float> img = readImage(dir);
    EXPECT_EQ(*std::min_element(img.voxels.begin(), img.voxels.end()), -1024.0f);
}

TEST(ImageIo, RealNiftiMatchesItsHeader)
{
    // example_ct_sm.nii.gz's header (first 8 of its 30 slices, header bytes kept): int16,
    // pixdim 3 3 3, qform_code 0, sform_code 2, srow_x = 3 0 0 -177.95632934570312,
    // srow_y = 0 3 0 11.319000244140625, srow_z = 0 0 3 94.3017578125 (RAS). In LPS: x and
    // y negated.
    auto source = openImage(fixture("real/example_ct_sm_8slices.nii.gz"));
    const ImageGeometry& g = source->geometry();
    EXPECT_EQ(g.size, (std::array<int64_t, 3>{122, 101, 8}));
    for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(g.spacingMm[c], 3.0);
    EXPECT_NEAR(g.originMm.x, 177.95632934570312, 1e-9);
    EXPECT_NEAR(g.originMm.y, -11.319000244140625, 1e-9);
    EXPECT_NEAR(g.originMm.z, 94.3017578125, 1e-9);
    const double want[3][3] = {{-1, 0, 0}, {0, -1, 0}, {0, 0, 1}};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(g.direction[r][c], want[r][c]);
    // Voxel (10, 20, 5) in RAS by the sform: (3*10 - 177.956, 3*20 + 11.319, 3*5 + 94.302).
    const Vec3d p = g.worldFromIndex({10, 20, 5});
    EXPECT_NEAR(p.x, -(30 - 177.95632934570312), 1e-9);
    EXPECT_NEAR(p.y, -(60 + 11.319000244140625), 1e-9);
    EXPECT_NEAR(p.z, 15 + 94.3017578125, 1e-9);
    const Image3<float> img = readImage(fixture("real/example_ct_sm_8slices.nii.gz"));
    EXPECT_EQ(img.at(0, 0, 0), -1024.0f);
}

TEST(ImageIo, FullRealNiftiWhenTheSharedDataIsThere)
{
    const std::string path = sharedReal("example_ct.nii.gz");
    if (!fs::exists(path)) GTEST_SKIP() << path << " is not in this checkout";
    auto source = openImage(path);  // int32 voxels
    EXPECT_EQ(source->geometry().size, (std::array<int64_t, 3>{122, 101, 112}));
    EXPECT_NEAR(source->geometry().originMm.x, 177.95632934570312, 1e-9);
}

TEST(ImageIo, EveryBadInputNamesTheFileAndTheProblem)
{
    struct Case { std::string path; std::string expect; };
    const std::vector<Case> cases{
        {"bad/truncated.nii.gz", "gzip data is truncated or corrupt"},
        {"bad/truncated.nii", "header/data size mismatch"},
        {"bad/corrupt_header.nii", "not a readable NIfTI file"},
        {"bad/bad_header.nrrd", "cannot read the NRRD header: _nrrdReadNrrdParse_sizes: parsed 2 values, but dimension is 3"},
        {"bad/size_mismatch.mhd", "header/data size mismatch"},
        {"bad/size_mismatch.nhdr", "cannot read the voxel data"},
        {"bad/huge.mha", "header/data size mismatch"},
        {"bad/rgb.mha", "a scalar (grey-value) image is needed"},
        {"bad/slice2d.nii", "image is 2D (20 x 16)"},
        {"bad/nan.mha", "voxel (3,4,2) is nan"},
        {"bad/inf.nrrd", "voxel (5,2,1) is inf"},
        {"bad/zero_spacing.mha", "voxel spacing along k (z) is 0 mm"},
        {"bad/negative_spacing.mha", "voxel spacing along j (y) is -1 mm"},
        {"bad/truncated_nifti2.nii", "header/data size mismatch"},
        {"bad/complex_nifti2.nii", "voxel type complex64 is not supported"},
        {"bad/dicom/missing_slice", "1 slice(s) missing between"},
        {"bad/dicom/uneven", "uneven slice spacing: 2 mm between"},
        {"bad/dicom/single_slice", "has a single slice"},
        {"bad/dicom/corrupt_slice", "pixel data is incomplete"},
        {"bad/gdcm_abort.dcm", "the image reader (ITK; GDCM for DICOM) crashed on its header"},
        {"bad/gdcm_huge_length.dcm", "not a readable DICOM file"},
        {"bad/metaio_overflow.mha", "MetaImage header line 4 has a field name longer than 64 characters"},
        {"bad/metaio_ascii_overrun.mha", "MetaImage header line 3 says BinaryData = *True: ASCII voxel data is not supported"},
        {"bad/metaio_ascii_overrun2.mha", "MetaImage header line 3 says BinaryData = /True: ASCII voxel data is not supported"},
        {"real/LICENSE", "not a readable image"},
    };
    for (const auto& c : cases) {
        const std::string msg = openError(fixture(c.path));
        EXPECT_NE(msg.find(c.expect), std::string::npos) << c.path << ": got \"" << msg << "\"";
        const std::string named = c.path == "bad/dicom/corrupt_slice" ? "corrupt_slice/IM02" : fs::path(c.path).filename().string();
        EXPECT_NE(msg.find(named), std::string::npos) << c.path << ": the message names the file: " << msg;
        EXPECT_EQ(msg.find('\n'), std::string::npos) << c.path << ": one line";
    }
}

TEST(ImageIo, AFileThatAbortsGdcmIsSkippedInAFolder)
{
    // Debian's GDCM abort()s on this header; the scan runs in child processes, so the file
    // is reported (here: skipped, the series beside it is complete) and the process lives.
    TempDir dir("abort");
    for (const auto& e : fs::directory_iterator(fixture("dicom/same"))) fs::copy_file(e.path(), dir.path / e.path().filename());
    fs::copy_file(fixture("bad/gdcm_abort.dcm"), dir.path / "broken.dcm");
    auto source = openImage(dir.path.string());
    EXPECT_EQ(source->geometry().size[2], FX_NZ);
    // Alone in its folder, it is the error.
    TempDir alone("abort-alone");
    fs::copy_file(fixture("bad/gdcm_abort.dcm"), alone.path / "broken.dcm");
    const std::string msg = openError(alone.path.string());
    EXPECT_NE(msg.find("broken.dcm: unreadable DICOM file: malformed file: the DICOM reader (GDCM) aborted"),
              std::string::npos) << msg;
}

TEST(ImageIo, MissingEmptyAndNonDicomFoldersAreRefused)
{
    EXPECT_NE(openError("/nonexistent/scan.nii.gz").find("no such file or directory"), std::string::npos);
    TempDir dir("folders");
    EXPECT_NE(openError(dir.path.string()).find("the folder is empty"), std::string::npos);
    std::ofstream(dir.path / "notes.txt") << "not an image";
    EXPECT_NE(openError(dir.path.string()).find("no DICOM image found"), std::string::npos);
    std::ofstream(dir.path / "empty.nii");
    EXPECT_NE(openError((dir.path / "empty.nii").string()).find("the file is empty"), std::string::npos);
}

TEST(ImageIo, GapsAreAcceptedOnlyWhenAllowedAndThenWarned)
{
    ImageReadOptions allow;
    allow.allowGaps = true;
    for (const char* name : {"bad/dicom/missing_slice", "bad/dicom/uneven"}) {
        EXPECT_THROW(openImage(fixture(name)), InputError) << name;
        auto source = openImage(fixture(name), allow);
        EXPECT_FALSE(source->isRegular()) << name;
        ASSERT_EQ(source->warnings().size(), 1u) << name;
        EXPECT_NE(source->warnings()[0].find("accepted (--allow-gaps)"), std::string::npos) << source->warnings()[0];
        // readImage() cannot express true positions: it refuses rather than shear.
        EXPECT_THROW(readImage(fixture(name), allow), InputError) << name;
    }
}

TEST(ImageIo, GantryTiltIsDetectedFromSlicePositions)
{
    auto source = openImage(fixture("dicom/tilt"));
    EXPECT_FALSE(source->isRegular());
    ASSERT_EQ(source->warnings().size(), 1u);
    const std::string& w = source->warnings()[0];
    EXPECT_NE(w.find("gantry tilt of 15 degrees"), std::string::npos) << w;
    EXPECT_NE(w.find("corrected"), std::string::npos) << w;
    EXPECT_THROW(readImage(fixture("dicom/tilt")), InputError) << "never a silently sheared dense image";
}

TEST(ImageIo, WrittenImagesReadBackUnchanged)
{
    TempDir dir("write");
    Image3<int16_t> img;
    img.geometry = fixtureGeometry();
    img.voxels.resize(static_cast<std::size_t>(img.geometry.voxelCount()));
    for (std::size_t n = 0; n < img.voxels.size(); ++n) img.voxels[n] = static_cast<int16_t>(int(n % 3001) - 1000);
    for (const char* ext : {".nii.gz", ".nrrd", ".mha"}) {
        const std::string path = (dir.path / (std::string("w") + ext)).string();
        writeImage(img, path);
        const Image3<float> back = readImage(path);
        expectGeometryNear(back.geometry, img.geometry, ext);
        for (std::size_t n = 0; n < img.voxels.size(); ++n) ASSERT_EQ(back.voxels[n], float(img.voxels[n])) << ext;
    }
}

TEST(ImageIo, MalformedMetaImageHeaderTextIsRefusedBeforeMetaIoReadsIt)
{
    // MetaIO copies names and values into fixed buffers (fuzzing found memory corruption that
    // the crash-isolated probe did not catch): the header text is checked first.
    TempDir dir("metatext");
    const std::string good = "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n";
    struct Case { std::string name, header, expect; };
    const std::vector<Case> cases{
        {"no_separator.mha", "ObjectType = Image\nNDims 3\nElementDataFile = LOCAL\n", "line 2 is not 'Name = value'"},
        {"long_line.mha", good + "Comment = " + std::string(1100, 'x') + "\nElementDataFile = LOCAL\n",
         "line 5 is longer than 1024 characters"},
        {"no_data_file.mhd", good, "has no ElementDataFile field"},
        {"bad_start.mha", good + "= 3\nElementDataFile = LOCAL\n", "line 5 does not start with a field name"},
        {"nul.mha", "ObjectType = Image\nNDims = 3\nDim" + std::string(1, '\0') + "Size = 2 2 2\nElementType = MET_SHORT\n"
                    "ElementDataFile = LOCAL\n", "line 3 holds a non-printable character"},
        // ASCII data: MetaIO's region reader overran the buffer (found by fuzzing, "/True").
        {"ascii.mha", "ObjectType = Image\nNDims = 3\nBinaryData = /True\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
                      "ElementDataFile = LOCAL\n", "line 3 says BinaryData = /True: ASCII voxel data is not supported"},
        {"ascii_false.mhd", "ObjectType = Image\nNDims = 3\nBinaryData = False\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
                            "ElementDataFile = LOCAL\n", "ASCII voxel data is not supported"},
        // 2^36 cubed overflows 64 bits: the size check must not wrap around.
        {"overflow.mha", "ObjectType = Image\nNDims = 3\nDimSize = 68719476736 68719476736 68719476736\n"
                         "ElementType = MET_SHORT\nElementDataFile = LOCAL\n", "more than any file holds"},
    };
    for (const Case& c : cases) {
        const fs::path p = dir.path / c.name;
        std::ofstream(p, std::ios::binary) << c.header << std::string(p.extension() == ".mha" ? 16 : 0, '\0');
        const std::string msg = openError(p.string());
        EXPECT_NE(msg.find(c.expect), std::string::npos) << c.name << ": expected \"" << c.expect << "\", got \"" << msg << "\"";
        EXPECT_EQ(msg.rfind(p.string(), 0), 0u) << c.name << ": " << msg;
    }
    // A well-formed header with blank lines, ':' separators and BinaryData = 1 still reads.
    const fs::path ok = dir.path / "ok.mha";
    std::ofstream(ok, std::ios::binary) << "ObjectType = Image\n\nNDims: 3\nBinaryData = 1\nDimSize = 2 2 2\nElementSpacing = 1 1 1\n"
                                           "ElementType = MET_SHORT\nElementDataFile = LOCAL\n"
                                        << std::string(16, '\0');
    EXPECT_EQ(openError(ok.string()), "");
}
