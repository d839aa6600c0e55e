// flyover: the command line. The only place that turns exceptions into exit codes.

#include "data/phantom.h"
#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/config_file.h"
#include "pipeline/export.h"
#include "pipeline/phantom_io.h"
#include "pipeline/params.h"
#include "pipeline/study.h"
#include "volume/error.h"

#include <CLI/CLI.hpp>
#include <openvdb/openvdb.h>
#include <tbb/global_control.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

int fail(const std::string& message, int code)
{
    std::cerr << "flyover: error: " << message << std::endl;
    return code;
}

} // namespace

int main(int argc, char** argv)
{
    CLI::App app{"flyover: CT scan -> colon lumen -> centerline -> surface -> one-sided-transparency "
                 "(OST) fly-over images.\nWorld coordinates are LPS millimetres (as in DICOM and ITK) "
                 "in every artifact."};
    app.require_subcommand(1);
    app.set_version_flag("--version", "flyover 0.1.0");
    int threads = 0;
    app.add_option("--threads", threads, "worker threads (0 = all cores)")->check(CLI::NonNegativeNumber);
    bool quiet = false, logJson = false;
    app.add_flag("-q,--quiet", quiet, "no progress output on stderr");
    app.add_flag("--log-json", logJson, "progress as JSON lines on stderr (for scripts)");

    // flyover phantom
    auto* phantomCmd = app.add_subcommand("phantom", "write a synthetic abdominal CT phantom with ground truth");
    std::string phantomOut, truthOut, maskOut, sizeName = "small";
    uint64_t seed = 1;
    double noiseHu = PhantomParams{}.noiseHu;
    phantomCmd->add_option("output", phantomOut, "CT output (.nii.gz, .nii, .nrrd, .mha)")->required();
    phantomCmd->add_option("--truth", truthOut, "ground-truth JSON: centerline, radii, polyps")->required();
    phantomCmd->add_option("--truth-mask", maskOut, "write the true lumen mask (uint8) here");
    phantomCmd->add_option("--size", sizeName, "small (160x160x150, 2.5 mm), medium (256x256x250), "
                                               "full (512x512x450, 0.78 mm)")
        ->capture_default_str();
    phantomCmd->add_option("--seed", seed, "random seed (polyps, pockets, noise)")->capture_default_str();
    phantomCmd->add_option("--noise-hu", noiseHu, "Gaussian noise standard deviation (HU)")->capture_default_str();

    // flyover run
    auto* runCmd = app.add_subcommand("run", "run ingest -> segment -> centerline + mesh -> render into a study folder");
    RunOptions run;
    std::vector<std::string> assignments;
    std::string configPath;
    runCmd->add_option("ct", run.ctPath, "CT scan: NIfTI, NRRD, MetaImage file or DICOM series folder")->required();
    runCmd->add_option("--study", run.studyDir, "study folder for artifacts and manifest.json")->required();
    runCmd->add_option("--config", configPath, "JSON file {\"stage\": {\"param\": value}} (see 'flyover params')");
    runCmd->add_option("--set", assignments, "stage.param=value (repeatable; see 'flyover params')");
    runCmd->add_option("--until", run.untilStage, "run only this stage and what it needs (ingest, segment, centerline, mesh, render)");
    runCmd->add_option("--force", run.forceStage, "recompute this stage and everything downstream");
    runCmd->add_flag("--wait", run.waitForLock, "wait for another run on the same study instead of refusing");
    runCmd->add_option("--cache-max-gb", run.cacheMaxGb, "cap on the study's cache; least recently used results are evicted")
        ->capture_default_str();
    // flyover status / clean
    auto* statusCmd = app.add_subcommand("status", "list each stage of a study as fresh, stale or missing, and why");
    StatusOptions status;
    std::vector<std::string> statusAssignments;
    std::string statusConfig;
    statusCmd->add_option("--study", status.studyDir, "study folder")->required();
    statusCmd->add_option("--ct", status.ctPath, "compare against this scan (default: the one recorded in the manifest)");
    statusCmd->add_option("--config", statusConfig, "parameters as 'run' would take them (default: those of the last run)");
    statusCmd->add_option("--set", statusAssignments, "stage.param=value, as for 'run'");
    auto* cleanCmd = app.add_subcommand("clean", "remove a study's artifacts, manifest and cache");
    std::string cleanDir;
    cleanCmd->add_option("--study", cleanDir, "study folder")->required();

    // flyover export
    auto* exportCmd = app.add_subcommand("export", "write a study's results in formats other tools load");
    std::string exportStudy, exportMeshPath;
    exportCmd->add_option("--study", exportStudy, "study folder")->required();
    exportCmd->add_option("--mesh", exportMeshPath, "lumen surface as .ply, .obj, .stl or .off (inward normals)");

    // flyover params
    auto* paramsCmd = app.add_subcommand("params", "list every stage parameter with its default");

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        return fail(std::string(e.what()) + " (see flyover --help)", 2);
    }

    std::unique_ptr<tbb::global_control> threadLimit;
    // --threads bounds every pool: oneTBB's (OpenVDB, Embree and our loops run on it) through
    // global_control, and ITK's own pool (image reading) through its documented variable.
    if (threads > 0) ::setenv("ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS", std::to_string(threads).c_str(), 1);
    if (threads > 0)
        threadLimit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                            static_cast<std::size_t>(threads));
    RunLog runLog(quiet ? RunLog::Mode::Quiet
                        : logJson ? RunLog::Mode::Json : RunLog::defaultMode(STDERR_FILENO),
                  std::cerr);
    auto log = [&runLog](const std::string& line) { runLog.message(line); };

    try {
        openvdb::initialize();
        if (*paramsCmd) {
            std::cout << "Stage parameters (set with --set stage.param=value or --config FILE):\n"
                      << describeParams();
            return 0;
        }
        if (*phantomCmd) {
            PhantomParams pp;
            pp.size = parsePhantomSize(sizeName);
            pp.seed = seed;
            pp.noiseHu = noiseHu;
            if (!(noiseHu >= 0)) throw ParameterError("--noise-hu: must be >= 0");
            const auto t0 = std::chrono::steady_clock::now();
            const Phantom ph = makePhantom(pp);
            writePhantom(ph, pp, phantomOut, truthOut, maskOut);
            const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            log("phantom " + sizeName + " seed " + std::to_string(seed) + " written to " + phantomOut +
                " (" + std::to_string(ph.truth.polyps.size()) + " polyps, " + std::to_string(s).substr(0, 5) + " s)");
            return 0;
        }
        if (*runCmd) {
            if (!configPath.empty()) applyParamsJson(run.params, readConfigFile(configPath), configPath);
            for (const auto& a : assignments) applyParamAssignment(run.params, a);
            run.log = &runLog;
            const auto t0 = std::chrono::steady_clock::now();
            const auto manifest = runPipeline(run);
            int computed = 0;
            for (const auto& s : manifest["stages"]) computed += s.value("computed", false) ? 1 : 0;
            const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            log("study " + fs::absolute(run.studyDir).string() + ": " + std::to_string(computed) + " of " +
                std::to_string(manifest["stages"].size()) + " stages computed, " + std::to_string(s).substr(0, 5) + " s");
            return 0;
        }
        if (*statusCmd) {
            status.paramsGiven = !statusConfig.empty() || !statusAssignments.empty();
            if (!statusConfig.empty()) applyParamsJson(status.params, readConfigFile(statusConfig), statusConfig);
            for (const auto& a : statusAssignments) applyParamAssignment(status.params, a);
            for (const auto& st : studyStatus(status))
                std::cout << st.stage << std::string(12 - std::min<std::size_t>(11, st.stage.size()), ' ') << st.state
                          << (st.reason.empty() ? "" : "  (" + st.reason + ")") << "\n";
            return 0;
        }
        if (*exportCmd) {
            bool any = false;
            if (!exportMeshPath.empty()) {
                exportMesh(exportStudy, exportMeshPath);
                log("surface written to " + exportMeshPath);
                any = true;
            }
            if (!any) throw ParameterError("export: name at least one output (--mesh)");
            return 0;
        }
        if (*cleanCmd) {
            cleanStudy(cleanDir);
            log("study " + cleanDir + " cleaned");
            return 0;
        }
    } catch (const StageError& e) {
        return fail(e.what(), 1);
    } catch (const StudyBusy& e) {
        return fail(e.what(), 3);
    } catch (const ParameterError& e) {
        return fail(e.what(), 2);
    } catch (const InputError& e) {
        return fail(e.what(), 1);
    } catch (const std::exception& e) {
        return fail(e.what(), 1);
    }
    return 0;
}
