// `flyover export --lumen` (colon/export.h: exportLumen) on phantom studies: the lumen mask
// written on the original scan's lattice, read back by the ingest stage's reader, matches the
// study's lumen mask.
#include "colon/phantom.h"
#include "pipeline/artifact_io.h"
#include "colon/export.h"
#include "colon/phantom_io.h"
#include "colon/colon_study.h"
#include "volume/error.h"
#include "volume/image_io.h"
#include "volume/ingest.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <string>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

class LumenExport : public ::testing::Test {
protected:
    void SetUp() override
    {
        openvdb::initialize();
        mDir = fs::temp_directory_path() / ("flyover-lumen-export-" + std::to_string(::getpid()));
        fs::remove_all(mDir);
        fs::create_directories(mDir);
    }
    void TearDown() override { fs::remove_all(mDir); }

    /// A fluid phantom (small, 2.5 mm) segmented by the pipeline up to the segment stage.
    RunOptions study(const std::string& name, double voxelMm)
    {
        PhantomParams pp;
        pp.seed = 4;
        pp.fluid = true;
        writePhantom(makePhantom(pp), pp, (mDir / "ct.nii.gz").string(), "", "");
        RunOptions run;
        run.ctPath = (mDir / "ct.nii.gz").string();
        run.studyDir = (mDir / name).string();
        run.untilStage = "segment";
        run.params.ingest.voxelMm = voxelMm;
        runPipeline(run);
        return run;
    }

    fs::path mDir;
};

openvdb::BoolGrid::Ptr studyMask(const RunOptions& run)
{
    return openvdb::gridPtrCast<openvdb::BoolGrid>(readGrid((fs::path(run.studyDir) / "lumen.vdb").string(), "lumen_mask"));
}

TEST_F(LumenExport, OnTheScansOwnLatticeItIsTheStudyMask)
{
    const RunOptions run = study("study", 0.0);  // the ingest grid is the scan's 2.5 mm lattice
    const std::string out = (mDir / "lumen.nii.gz").string();
    exportLumen(run.studyDir, out);

    // Read back as the ingest stage reads a scan: same lattice, so voxel for voxel.
    const Image3<float> back = readImage(out);
    const Image3<float> ct = readImage(run.ctPath);
    EXPECT_EQ(back.geometry.size, ct.geometry.size);
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(back.geometry.spacingMm[c], ct.geometry.spacingMm[c], 1e-5);
        EXPECT_NEAR(back.geometry.originMm[c], ct.geometry.originMm[c], 1e-4);
    }
    auto hu = ingestImage(back, IngestParams{});
    const auto mask = studyMask(run);
    auto acc = mask->getConstAccessor();
    int64_t differ = 0, inside = 0;
    for (auto it = hu->cbeginValueOn(); it; ++it) {
        const bool exported = *it > 0.5f;
        inside += exported;
        differ += exported != acc.isValueOn(it.getCoord());
    }
    EXPECT_EQ(differ, 0);
    EXPECT_EQ(inside, int64_t(mask->activeVoxelCount()));
}

TEST_F(LumenExport, FromAResampledStudyItOverlaysTheStudyMask)
{
    // The study's grid is 2 mm, the scan's 2.5 mm: the export lands on the scan's lattice, and
    // ingesting it at 2 mm again gives back the study's mask but for boundary voxels.
    const RunOptions run = study("study2", 2.0);
    const std::string out = (mDir / "lumen.nrrd").string();
    exportLumen(run.studyDir, out);
    const Image3<float> back = readImage(out);
    EXPECT_EQ(back.geometry.size, readImage(run.ctPath).geometry.size);
    IngestParams ip;
    ip.voxelMm = 2.0;
    auto hu = ingestImage(back, ip);
    const auto mask = studyMask(run);
    EXPECT_TRUE(hu->transform() == mask->transform());
    auto acc = mask->getConstAccessor();
    int64_t both = 0, exported = 0;
    for (auto it = hu->cbeginValueOn(); it; ++it)
        if (*it > 0.5f) {
            ++exported;
            both += acc.isValueOn(it.getCoord());
        }
    const double dice = 2.0 * double(both) / double(exported + int64_t(mask->activeVoxelCount()));
    std::cout << "[ measure  ] exported 2.5 mm mask re-ingested at 2 mm vs the study mask: Dice " << dice << "\n";
    // Two trilinear resamplings (2 -> 2.5 -> 2 mm) of a binary mask move boundary voxels only.
    EXPECT_GE(dice, 0.97);
}

TEST_F(LumenExport, RefusesAFolderThatIsNoStudy)
{
    EXPECT_THROW(exportLumen(mDir.string(), (mDir / "x.nii.gz").string()), InputError);
}

} // namespace
