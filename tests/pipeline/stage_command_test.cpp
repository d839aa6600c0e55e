// `flyover stage NAME --study DIR` (one stage for workflow engines), its receipts and exit codes,
// the classification of failures as retryable or not, and a study that moves keeping its cache.

#include "tests/pipeline/cli_runner.h"
#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/stage_command.h"
#include "tests/pipeline/study_fixture.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cerrno>
#include <filesystem>
#include <fstream>
#include <new>
#include <system_error>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

/// The quick render settings of StudyTest::options() as command-line assignments.
const std::string QUICK = " --set render.width_px=96 --set render.height_px=96 --set render.frame_step_mm=150"
                          " --set render.overview_px=128 --set render.coverage_px=32"
                          " --set render.coverage_step_mm=20 --set render.video=false --set render.video_step_mm=50";

nlohmann::json receipt(const std::string& study, const std::string& stage)
{
    return readJson(receiptPath(study, stage));
}

std::string fileText(const fs::path& p)
{
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), {}};
}

} // namespace

TEST_F(StudyTest, StageCommandRunsStagesOneByOneWithReceipts)
{
    const std::string study = studyDir("stages");
    const std::string args = " --study " + study + " --ct " + ctPath() + QUICK;
    for (const char* stage : {"ingest", "segment", "centerline", "mesh", "render", "polyps"}) {
        const CliResult r = runFlyover(std::string("-q stage ") + stage + args);
        ASSERT_EQ(r.exitCode, 0) << stage << ": " << r.err;
        const auto rec = receipt(study, stage);
        EXPECT_EQ(rec.value("status", ""), "ok") << rec.dump();
        EXPECT_EQ(rec.value("stage", ""), stage);
        EXPECT_TRUE(rec.value("computed", false)) << stage << " was not computed by its own call";
        EXPECT_FALSE(rec["outputs"].empty()) << rec.dump();
    }
    // The same study through `run` with the same parameters: everything is already there.
    RunOptions o = options("stages");
    const auto manifest = runPipeline(o);
    for (const auto& [stage, computed] : computedStages(manifest)) EXPECT_FALSE(computed) << stage << " recomputed";
    // The receipts name the same artifacts with the same digests as the manifest.
    nlohmann::json fromManifest = nlohmann::json::object(), fromReceipts = nlohmann::json::object();
    for (const auto& [stage, digests] : outputDigests(manifest)) fromManifest.update(digests);
    for (const auto& stage : stageNames()) fromReceipts.update(receipt(study, stage)["outputs"]);
    EXPECT_EQ(fromManifest, fromReceipts);

    // A second stage call reuses, and says so.
    const CliResult again = runFlyover("-q stage mesh" + args);
    ASSERT_EQ(again.exitCode, 0) << again.err;
    EXPECT_FALSE(receipt(study, "mesh").value("computed", true));
}

TEST_F(StudyTest, StageCommandRefusesMissingOrStaleUpstreamWithExit4)
{
    const std::string study = studyDir("notready");
    const CliResult none = runFlyover("-q stage segment --study " + study + " --ct " + ctPath());
    EXPECT_EQ(none.exitCode, EXIT_NOT_READY) << none.err;
    EXPECT_NE(none.err.find("ingest"), std::string::npos) << none.err;
    EXPECT_FALSE(fs::exists(receiptPath(study, "segment"))) << "a refused stage left a receipt";

    ASSERT_EQ(runFlyover("-q stage ingest --study " + study + " --ct " + ctPath()).exitCode, 0);
    const CliResult missing = runFlyover("-q stage centerline --study " + study);  // CT from the manifest
    EXPECT_EQ(missing.exitCode, EXIT_NOT_READY) << missing.err;
    EXPECT_NE(missing.err.find("segment"), std::string::npos) << "the message names the missing stage: " << missing.err;
    EXPECT_EQ(lineCount(missing.err), 1) << missing.err;

    ASSERT_EQ(runFlyover("-q stage segment --study " + study).exitCode, 0);
    // Other segment parameters than those segment ran with: stale, and the reason is named.
    const CliResult stale = runFlyover("-q stage centerline --study " + study + " --set segment.cleanse=false");
    EXPECT_EQ(stale.exitCode, EXIT_NOT_READY) << stale.err;
    EXPECT_NE(stale.err.find("segment.cleanse"), std::string::npos) << stale.err;
    EXPECT_FALSE(fs::exists(study + "/centerline.json")) << "the stage ran although segment was stale";
    // Nothing upstream was recomputed behind the caller's back.
    EXPECT_TRUE(receipt(study, "segment").value("computed", false));
}

TEST_F(StudyTest, StageCommandRecordsABadScanAndLaterStagesFailAtOnce)
{
    const std::string study = studyDir("badscan");
    const std::string broken = studyDir("broken.nii.gz");
    {
        const std::string full = fileText(ctPath());
        std::ofstream(broken, std::ios::binary) << full.substr(0, full.size() / 4);
    }
    const CliResult ingest = runFlyover("-q stage ingest --study " + study + " --ct " + broken);
    EXPECT_EQ(ingest.exitCode, EXIT_BAD_INPUT) << ingest.err;
    const auto rec = receipt(study, "ingest");
    EXPECT_EQ(rec.value("status", ""), "failed");
    EXPECT_EQ(rec.value("exit_code", 0), EXIT_BAD_INPUT);
    const std::string error = rec.value("error", "");
    EXPECT_NE(error.find("broken.nii.gz"), std::string::npos) << "the error names the file: " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;

    const CliResult segment = runFlyover("-q stage segment --study " + study + " --ct " + broken);
    EXPECT_EQ(segment.exitCode, EXIT_BAD_INPUT) << segment.err;
    EXPECT_NE(segment.err.find("ingest failed earlier"), std::string::npos) << segment.err;
    EXPECT_NE(receipt(study, "segment").value("error", "").find("broken.nii.gz"), std::string::npos);

    // A per-scan parameter error is the scan's failure too: exit 2, receipt "failed".
    const CliResult param = runFlyover("-q stage ingest --study " + studyDir("badparam") + " --ct " + ctPath() +
                                       " --set ingest.voxel_mm=-3");
    EXPECT_EQ(param.exitCode, EXIT_BAD_PARAMETER) << param.err;
    EXPECT_EQ(receipt(studyDir("badparam"), "ingest").value("exit_code", 0), EXIT_BAD_PARAMETER);
    // An unknown stage name is a bad command line: exit 2, no receipt anywhere.
    const CliResult unknown = runFlyover("-q stage colour --study " + study);
    EXPECT_EQ(unknown.exitCode, EXIT_BAD_PARAMETER) << unknown.err;
    EXPECT_FALSE(fs::exists(receiptPath(study, "colour")));
}

TEST_F(StudyTest, StageCommandOnABusyStudyIsATemporaryFailure)
{
    const std::string study = studyDir("busy");
    ASSERT_EQ(runFlyover("-q stage ingest --study " + study + " --ct " + ctPath()).exitCode, 0);
    StudyLock held(study, false);
    const CliResult r = runFlyover("-q stage ingest --study " + study + " --ct " + ctPath());
    EXPECT_EQ(r.exitCode, EXIT_TEMPFAIL) << r.err;
    EXPECT_NE(r.err.find("another flyover run"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(receiptPath(study, "ingest"))) << "a retryable failure must not leave a receipt";
    // `run` keeps its own code for the same case.
    EXPECT_EQ(runFlyover("-q run " + ctPath() + " --study " + study + " --until ingest").exitCode, EXIT_STUDY_BUSY);
}

TEST(StageExitCodes, TransientCausesAreRetryableOthersAreNot)
{
    auto codeOf = [](auto&& thrower) {
        try {
            thrower();
        } catch (...) {
            return exitCodeFor(std::current_exception());
        }
        return -1;
    };
    EXPECT_EQ(codeOf([] { throw TransientError("x: cannot write: No space left on device"); }), EXIT_TEMPFAIL);
    EXPECT_EQ(codeOf([] { throw std::bad_alloc(); }), EXIT_TEMPFAIL);
    EXPECT_EQ(codeOf([] {
                  throw fs::filesystem_error("rename", std::error_code(ENOSPC, std::generic_category()));
              }),
              EXIT_TEMPFAIL);
    EXPECT_EQ(codeOf([] {
                  throw fs::filesystem_error("rename", std::error_code(ENOENT, std::generic_category()));
              }),
              EXIT_BAD_INPUT);
    // A stage's failure nests its cause: out of memory inside a stage is retryable...
    EXPECT_EQ(codeOf([] {
                  try {
                      throw std::bad_alloc();
                  } catch (const std::exception& e) {
                      std::throw_with_nested(StageError("mesh", e.what()));
                  }
              }),
              EXIT_TEMPFAIL);
    // ...a bad scan inside a stage is not.
    EXPECT_EQ(codeOf([] {
                  try {
                      throw InputError("ct.nii.gz: truncated");
                  } catch (const std::exception& e) {
                      std::throw_with_nested(StageError("ingest", e.what()));
                  }
              }),
              EXIT_BAD_INPUT);
    EXPECT_EQ(codeOf([] { throw ParameterError("render.fov_deg: must be in [10, 170]"); }), EXIT_BAD_PARAMETER);
    EXPECT_EQ(codeOf([] { throw StudyBusy("busy"); }), EXIT_STUDY_BUSY);
    EXPECT_EQ(codeOf([] { throw StageNotReady("not ready"); }), EXIT_NOT_READY);
}

TEST(StageExitCodes, AFullDiskDuringAnAtomicWriteIsTransientAndLeavesNothing)
{
    const fs::path dir = fs::temp_directory_path() / ("flyover-enospc-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const std::string target = (dir / "out.json").string();
    try {
        // A writer that fails as std::ofstream does on a full disk: errno set, a bare message.
        writeAtomically(target, [](const std::string& tmp) {
            std::ofstream(tmp) << "partial";
            errno = ENOSPC;
            throw InputError(tmp + ": cannot write");
        });
        FAIL() << "the failed write was not reported";
    } catch (const TransientError& e) {
        EXPECT_NE(std::string(e.what()).find("out.json"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("No space left"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(target));
    EXPECT_TRUE(fs::is_empty(dir)) << "the temporary file was left behind";
    // A writer that fails for a reason of its own stays what it was.
    EXPECT_THROW(writeAtomically(target, [](const std::string&) { throw InputError("bad image"); }), InputError);
    fs::remove_all(dir);
}

TEST_F(StudyTest, MovedStudyKeepsItsCache)
{
    // A study moved to another place (another mount of a shared file system, another machine):
    // its records and objects are relative to the study folder, so nothing is recomputed.
    RunOptions o = options("before-move");
    runPipeline(o);
    const std::string moved = studyDir("elsewhere/after-move");
    fs::create_directories(fs::path(moved).parent_path());
    fs::rename(o.studyDir, moved);
    for (const auto& e : fs::recursive_directory_iterator(moved + "/.flyover/records"))
        EXPECT_EQ(fileText(e.path()).find("before-move"), std::string::npos)
            << e.path() << " records the study's old path";
    o.studyDir = moved;
    for (const auto& [stage, computed] : computedStages(runPipeline(o))) EXPECT_FALSE(computed) << stage << " recomputed";

    // A copy that does not keep hard links (rsync without -H, a copy between machines) too.
    const std::string copied = studyDir("copied");
    fs::copy(moved, copied, fs::copy_options::recursive);
    o.studyDir = copied;
    for (const auto& [stage, computed] : computedStages(runPipeline(o))) EXPECT_FALSE(computed) << stage << " recomputed";
    const CliResult status = runFlyover("status --study " + copied);
    EXPECT_EQ(status.exitCode, 0) << status.err;
    EXPECT_EQ(status.out.find("stale"), std::string::npos) << status.out;
}
