// Ingest through the command line: every bad scan gives one line naming the file and the
// problem, exit code 1, and no grid in the study; the ingest options (--series, --voxel-mm,
// --allow-gaps) reach the stage; the manifest records frame, memory and file size.

#include "tests/pipeline/cli_runner.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;

namespace {

using Result = flyover::test::CliResult;
using flyover::test::lineCount;
using flyover::test::runFlyover;

std::string fixture(const std::string& name) { return std::string(FLYOVER_SOURCE_DIR) + "/data/fixtures/" + name; }

class IngestCli : public ::testing::Test {
protected:
    void SetUp() override
    {
        mStudy = fs::temp_directory_path() / ("flyover-ingest-cli-study-" + std::to_string(::getpid()));
        fs::remove_all(mStudy);
    }
    void TearDown() override { fs::remove_all(mStudy); }

    Result ingest(const std::string& scan, const std::string& extra = "", bool quiet = true)
    {
        fs::remove_all(mStudy);
        return runFlyover(std::string(quiet ? "--quiet " : "") + "run " + scan + " --study " + mStudy.string() +
                          " --until ingest " + extra);
    }
    nlohmann::json ingestReport() const
    {
        std::ifstream in(mStudy / "manifest.json");
        const auto m = nlohmann::json::parse(in);
        return m.at("stages").at(0).at("report");
    }
    fs::path mStudy;
};

} // namespace

TEST_F(IngestCli, EveryBadScanGivesOneLineNamingItAndExitCode1)
{
    struct Case { const char* path; const char* expect; };
    for (const Case& c : {Case{"bad/truncated.nii.gz", "gzip data is truncated or corrupt"},
                          Case{"bad/truncated.nii", "header/data size mismatch"},
                          Case{"bad/corrupt_header.nii", "not a readable NIfTI file"},
                          Case{"bad/bad_header.nrrd", "cannot read the NRRD header"},
                          Case{"bad/size_mismatch.mhd", "header/data size mismatch"},
                          Case{"bad/size_mismatch.nhdr", "cannot read the voxel data"},
                          Case{"bad/huge.mha", "header/data size mismatch"},
                          Case{"bad/rgb.mha", "a scalar (grey-value) image is needed"},
                          Case{"bad/slice2d.nii", "image is 2D"},
                          Case{"bad/nan.mha", "is nan; NaN and Inf voxels are not allowed"},
                          Case{"bad/inf.nrrd", "is inf; NaN and Inf voxels are not allowed"},
                          Case{"bad/zero_spacing.mha", "voxel spacing along k (z) is 0 mm"},
                          Case{"bad/negative_spacing.mha", "voxel spacing along j (y) is -1 mm"},
                          Case{"bad/dicom/missing_slice", "1 slice(s) missing between"},
                          Case{"bad/dicom/uneven", "uneven slice spacing"},
                          Case{"bad/dicom/single_slice", "has a single slice"},
                          Case{"bad/dicom/corrupt_slice", "IM02: pixel data is incomplete"},
                          Case{"bad/truncated_nifti2.nii", "header/data size mismatch"},
                          Case{"bad/complex_nifti2.nii", "voxel type complex64 is not supported"},
                          Case{"bad/gdcm_abort.dcm", "the image reader (ITK; GDCM for DICOM) crashed on its header"},
                          Case{"bad/gdcm_huge_length.dcm", "not a readable DICOM file"},
                          Case{"bad/metaio_overflow.mha", "MetaImage header line 4 has a field name longer than 64"},
                          Case{"bad/metaio_ascii_overrun.mha", "BinaryData = *True: ASCII voxel data is not supported"},
                          Case{"bad/metaio_ascii_overrun2.mha", "BinaryData = /True: ASCII voxel data is not supported"},
                          Case{"bad/data_file_pattern.mhd", "ElementDataFile 'slice%03d.raw 1 2 1' is a file list or pattern"}}) {
        const Result r = ingest(fixture(c.path));
        EXPECT_EQ(r.exitCode, 1) << c.path << "\n" << r.err;
        EXPECT_EQ(lineCount(r.err), 1) << c.path << "\n" << r.err;
        EXPECT_EQ(r.err.rfind("flyover: error: ingest: ", 0), 0u) << c.path << "\n" << r.err;
        EXPECT_NE(r.err.find(fs::path(c.path).filename().string()), std::string::npos) << c.path << "\n" << r.err;
        EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.path << "\n" << r.err;
        EXPECT_FALSE(fs::exists(mStudy / "ct.vdb")) << c.path << ": nothing written to the study";
    }
}

TEST_F(IngestCli, BadIngestParametersGiveExitCode2)
{
    for (const char* extra : {"--voxel-mm -1", "--voxel-mm abc", "--set ingest.voxel_mm=-2", "--set ingest.allow_gaps=3",
                              "--set ingest.nope=1"}) {
        const Result r = ingest(fixture("same.mha"), extra);
        EXPECT_EQ(r.exitCode, 2) << extra << "\n" << r.err;
        EXPECT_EQ(lineCount(r.err), 1) << extra << "\n" << r.err;
    }
}

TEST_F(IngestCli, AllowGapsWarnsAndIngests)
{
    const Result refused = ingest(fixture("bad/dicom/missing_slice"));
    EXPECT_EQ(refused.exitCode, 1);
    EXPECT_NE(refused.err.find("--allow-gaps"), std::string::npos) << refused.err;

    const Result r = ingest(fixture("bad/dicom/missing_slice"), "--allow-gaps", false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("ingest: warning: "), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("missing between"), std::string::npos) << r.err;
    const auto rep = ingestReport();
    EXPECT_EQ(rep.at("warnings").size(), 1u);
    EXPECT_TRUE(fs::exists(mStudy / "ct.vdb"));
}

TEST_F(IngestCli, GantryTiltIsCorrectedWithAWarning)
{
    const Result r = ingest(fixture("dicom/tilt"), "", false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("gantry tilt of 15 degrees"), std::string::npos) << r.err;
    EXPECT_NE(ingestReport().at("interpolation").get<std::string>().find("true positions"), std::string::npos);
}

TEST_F(IngestCli, SeriesAndVoxelSizeOptionsReachTheStage)
{
    ASSERT_EQ(ingest(fixture("dicom/two_series"), "--series 1.2.826.0.1.3680043.2.1125.77.2.41 --voxel-mm 1.25").exitCode, 0);
    auto rep = ingestReport();
    EXPECT_EQ(rep.at("input_size")[2], 4);
    EXPECT_DOUBLE_EQ(rep.at("voxel_mm").get<double>(), 1.25);
    EXPECT_TRUE(rep.at("warnings").empty());

    const Result r = ingest(fixture("dicom/two_series"), "--series 9.9.9");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.err.find("no DICOM series 9.9.9"), std::string::npos) << r.err;
}

TEST_F(IngestCli, ManifestRecordsFrameMemoryAndFileOfACompressedGrid)
{
    ASSERT_EQ(ingest(fixture("dicom/same_j2k")).exitCode, 0);
    const auto rep = ingestReport();
    EXPECT_EQ(rep.at("world_frame"), "LPS");
    EXPECT_GT(rep.at("active_voxels").get<int64_t>(), 2000);
    EXPECT_GT(rep.at("memory_bytes").get<int64_t>(), 0);
    EXPECT_EQ(rep.at("file_bytes").get<int64_t>(), static_cast<int64_t>(fs::file_size(mStudy / "ct.vdb")));
    EXPECT_GT(rep.at("process_peak_rss_bytes").get<int64_t>(), 0);
    EXPECT_NE(rep.at("reader").get<std::string>().find("GDCM"), std::string::npos);
    // vdb_print (libopenvdb-tools) opens it, when installed.
    if (std::system("command -v vdb_print >/dev/null 2>&1") == 0) {
        const std::string cmd = "vdb_print -l " + (mStudy / "ct.vdb").string() + " >/dev/null 2>&1";
        EXPECT_EQ(std::system(cmd.c_str()), 0);
    }
}
