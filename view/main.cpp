// flyover: the command line. The only place that turns exceptions into exit codes.

#include "colon/phantom.h"
#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/config_file.h"
#include "colon/export.h"
#include "inspect/part_phantom_io.h"
#include "colon/phantom_io.h"
#include "colon/colon_study.h"
#include "colon/params.h"
#include "colon/report.h"
#include "inspect/inspect_study.h"
#include "pipeline/stage_command.h"
#include "pipeline/study.h"
#include "view/view_server.h"
#include "volume/error.h"

#include <CLI/CLI.hpp>
#include <openvdb/openvdb.h>
#include <tbb/global_control.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
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

using Log = std::function<void(const std::string&)>;

/// `flyover phantom`: a synthetic CT (colon or part) with its truth.
struct PhantomCommand {
    CLI::App* phantomCmd = nullptr;
    std::string phantomOut, truthOut, maskOut, sizeName = "small";
    uint64_t seed = 1;
    double noiseHu = PhantomParams{}.noiseHu;
    bool phantomFluid = false, phantomCollapse = false;
    bool phantomStricture = false;
    int phantomTouching = 0;
    bool phantomRedundant = false, phantomTube = false;
    std::string phantomSpacing;
    bool phantomPart = false;
    int partPores = 0;
    bool phantomProne = false, phantomIleum = false;
    std::string phantomOrientation = "LPS";

    void define(CLI::App& app)
    {
        phantomCmd = app.add_subcommand("phantom", "write a synthetic abdominal CT phantom with ground truth");
        phantomCmd->add_option("output", phantomOut, "CT output (.nii.gz, .nii, .nrrd, .mha)")->required();
        phantomCmd->add_option("--truth", truthOut, "ground-truth JSON: centerline, radii, polyps")->required();
        phantomCmd->add_option("--truth-mask", maskOut, "write the true lumen mask (uint8) here");
        phantomCmd->add_option("--size", sizeName, "small (160x160x150, 2.5 mm), medium (256x256x250), "
                                                   "full (512x512x450, 0.78 mm)")
            ->capture_default_str();
        phantomCmd->add_option("--seed", seed, "random seed (polyps, pockets, noise)")->capture_default_str();
        phantomCmd->add_option("--noise-hu", noiseHu, "Gaussian noise standard deviation (HU)")->capture_default_str();
        phantomCmd->add_flag("--fluid", phantomFluid, "tagged fluid (+300..+600 HU) below flat air-fluid levels "
                                                      "(supine: posterior); truth lumen = air + fluid");
        phantomCmd->add_flag("--collapse", phantomCollapse, "one or two collapsed 20-40 mm stretches of the sigmoid "
                                                            "(2 or 3 lumen pieces); the truth lists them");
        phantomCmd->add_flag("--stricture", phantomStricture, "the transverse colon narrowed abruptly to a radius of "
                                                              "max(3 mm, 1.6 voxels) over 8-12 mm (one piece, its core "
                                                              "split); the truth lists it");
        phantomCmd->add_option("--touching", phantomTouching, "N places where loops far apart along the colon press "
                                                              "together and their air joins (at most 2, with --redundant 5); "
                                                              "the truth lists them")
            ->check(CLI::Range(0, PHANTOM_MAX_CONTACTS));
        phantomCmd->add_flag("--redundant", phantomRedundant, "a redundant colon (extra sigmoid and transverse loops, "
                                                              "about 2.0-2.1 m)");
        phantomCmd->add_flag("--rectal-tube", phantomTube, "an air-filled rectal catheter from the outside air into the rectum");
        phantomCmd->add_flag("--part", phantomPart, "an industrial CT of a cast part (bore, flange, pores, an internal and an "
                                                    "open crack; uint16, written slab by slab; .nii, .nii.gz, .nrrd); "
                                                    "--size N voxels (112..2048, default 128)");
        phantomCmd->add_option("--pores", partPores, "with --part: number of pores (default 12 x (N/128)^2)")
            ->check(CLI::Range(0, 100000));
        phantomCmd->add_option("--spacing", phantomSpacing, "SX,SY,SZ voxel size in mm (same field of view), e.g. "
                                                            "0.8,0.8,1.25; default: the size's");
        phantomCmd->add_flag("--ileal-reflux", phantomIleum, "gas refluxed through the ileocecal valve fills ~170 mm of "
                                                             "terminal ileum joined to the cecum (not in the truth mask)");
        phantomCmd->add_flag("--prone", phantomProne, "with --fluid: the patient lies prone, the fluid pools anterior "
                                                      "(sigmoid, transverse colon)");
        phantomCmd->add_option("--orientation", phantomOrientation,
                               "voxel order: three letters naming where index axes i, j, k point, as nibabel's axis "
                               "codes (LPS: identity; RAS: a prone DICOM's; LAS: mirrored; SLP: sagittal); the same "
                               "world anatomy")
            ->capture_default_str();
    }

    int execute(RunLog& runLog, const Log& log)
    {
        if (phantomPart) {
            if (!maskOut.empty()) throw ParameterError("--truth-mask: not available with --part");
            // The colon's variants do not apply to a part: refused, not ignored.
            for (const auto& [flag, given] : {std::pair<const char*, bool>{"--fluid", phantomFluid},
                                              {"--collapse", phantomCollapse}, {"--stricture", phantomStricture},
                                              {"--touching", phantomTouching != 0}, {"--redundant", phantomRedundant},
                                              {"--rectal-tube", phantomTube}, {"--spacing", !phantomSpacing.empty()},
                                              {"--prone", phantomProne}, {"--orientation", phantomOrientation != "LPS"},
                                              {"--ileal-reflux", phantomIleum}})
                if (given) throw ParameterError(std::string(flag) + ": a colon phantom's option, not available with --part");
            PartPhantomParams pp;
            pp.size = sizeName == "small" ? 128 : parsePartSize(sizeName);
            pp.seed = seed;
            pp.pores = partPores;
            const auto t0 = std::chrono::steady_clock::now();
            const PartTruth truth = writePartPhantom(pp, phantomOut, truthOut);
            const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            log("part phantom " + std::to_string(pp.size) + "^3 seed " + std::to_string(seed) + " written to " +
                phantomOut + " (" + std::to_string(truth.voids.size()) + " voids, porosity " +
                std::to_string(truth.porosityPercent).substr(0, 6) + "%, " + std::to_string(s).substr(0, 5) + " s)");
            return 0;
        }
        if (partPores != 0) throw ParameterError("--pores: only with --part");
        PhantomParams pp;
        pp.size = parsePhantomSize(sizeName);
        pp.seed = seed;
        pp.noiseHu = noiseHu;
        pp.fluid = phantomFluid;
        pp.collapse = phantomCollapse;
        pp.stricture = phantomStricture;
        pp.touching = phantomTouching;
        pp.redundant = phantomRedundant;
        pp.rectalTube = phantomTube;
        pp.prone = phantomProne;
        pp.ilealReflux = phantomIleum;
        pp.orientation = phantomOrientation;
        if (!phantomSpacing.empty()) pp.spacingMm = parsePhantomSpacing(phantomSpacing);
        if (!(noiseHu >= 0)) throw ParameterError("--noise-hu: must be >= 0");
        const auto t0 = std::chrono::steady_clock::now();
        const Phantom ph = makePhantom(pp);
        writePhantom(ph, pp, phantomOut, truthOut, maskOut);
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        log("phantom " + sizeName + " seed " + std::to_string(seed) + " written to " + phantomOut +
            " (" + std::to_string(ph.truth.polyps.size()) + " polyps, " + std::to_string(s).substr(0, 5) + " s)");
        return 0;
    }
};

/// `flyover run`: the colon pipeline into a study folder.
struct RunCommand {
    CLI::App* runCmd = nullptr;
    RunOptions run;
    std::vector<std::string> assignments;
    std::string configPath;
    CLI::Option* maskOpt = nullptr;
    std::string seriesUid;
    double voxelMm = -1;
    bool allowGaps = false;
    CLI::Option* seriesOpt = nullptr;
    CLI::Option* voxelOpt = nullptr;
    std::string seedMm, cleanse;
    int maskLabel = 0;
    CLI::Option* seedOpt = nullptr;
    CLI::Option* cleanseOpt = nullptr;
    CLI::Option* labelOpt = nullptr;
    std::string rectumMm;
    double stepMm = 1.0;
    CLI::Option* rectumOpt = nullptr;
    CLI::Option* stepOpt = nullptr;

    void define(CLI::App& app)
    {
        runCmd = app.add_subcommand("run", "run ingest -> segment -> centerline + mesh -> render into a study folder");
        runCmd->add_option("ct", run.ctPath, "CT scan: NIfTI, NRRD, MetaImage file or DICOM series folder "
                                             "(optional with --mask)");
        maskOpt = runCmd->add_option("--mask", run.maskPath, "lumen mask or label map (NIfTI, NRRD, MetaImage): the "
                                                                   "lumen is taken from it instead of the CT's air; "
                                                                   "alone, it is the whole input");
        runCmd->add_option("--study", run.studyDir, "study folder for artifacts and manifest.json")->required();
        runCmd->add_option("--config", configPath, "JSON file {\"stage\": {\"param\": value}} (see 'flyover params')");
        runCmd->add_option("--set", assignments, "stage.param=value (repeatable; see 'flyover params')");
        runCmd->add_option("--until", run.untilStage, "run only this stage and what it needs (ingest, segment, centerline, mesh, frames, flythrough, "
                                            "overviews, video, coverage, polyps; render = all five render steps)");
        runCmd->add_option("--force", run.forceStage, "recompute this stage and everything downstream");
        runCmd->add_flag("--wait", run.waitForLock, "wait for another run on the same study instead of refusing");
        runCmd->add_option("--cache-max-gb", run.cacheMaxGb, "cap on the study's cache; least recently used results are evicted")
            ->capture_default_str();
        // Ingest shortcuts (same as --set ingest.*; they win over --config and --set).
        seriesOpt = runCmd->add_option("--series", seriesUid, "DICOM folder: read the series with this Series Instance UID "
                                                                    "(default: the one with the most slices)");
        voxelOpt = runCmd->add_option("--voxel-mm", voxelMm, "isotropic voxel size of the HU grid in mm "
                                                                   "(default: the smallest input spacing)")
                             ->check(CLI::PositiveNumber);
        runCmd->add_flag("--allow-gaps", allowGaps, "DICOM: accept missing slices or uneven slice steps (with a warning), "
                                                    "interpolating at the true slice positions");
        // Segment shortcuts (same as --set segment.*; they win over --config and --set).
        seedOpt = runCmd->add_option("--seed-mm", seedMm, "x,y,z (LPS mm): the colon is the air component "
                                                                "containing this point (default: the largest)");
        cleanseOpt = runCmd->add_option("--cleanse", cleanse, "on|off: join tagged fluid under air-fluid levels "
                                                                    "to the lumen (default on)")
                               ->check(CLI::IsMember({"on", "off"}));
        labelOpt = runCmd->add_option("--label", maskLabel, "with --mask: the label that is lumen "
                                                                  "(default 0: every non-zero voxel)")
                             ->check(CLI::NonNegativeNumber);
        labelOpt->needs(maskOpt);

        // Centerline shortcuts (same as --set centerline.*; they win over --config and --set).
        rectumOpt = runCmd->add_option("--rectum-mm", rectumMm, "x,y,z (LPS mm): the path starts at the lumen end "
                                                                      "nearest this point (default: the lowest end)");
        stepOpt = runCmd->add_option("--step-mm", stepMm, "arc-length step of the centerline (mm, default 1)")
                            ->check(CLI::PositiveNumber);
    }

    int execute(RunLog& runLog, const Log& log)
    {
        if (!configPath.empty()) applyParamsJson(run.params, readConfigFile(configPath), configPath);
        for (const auto& a : assignments) applyParamAssignment(run.params, a);
        if (*seriesOpt) run.params.ingest.dicomSeries = seriesUid;
        if (*voxelOpt) run.params.ingest.voxelMm = voxelMm;
        if (allowGaps) run.params.ingest.allowGaps = true;
        if (*seedOpt) applyParamsJson(run.params, {{"segment", {{"seed_mm", seedMm}}}}, "--seed-mm");
        if (*cleanseOpt) run.params.segment.cleanse = cleanse == "on";
        if (*labelOpt) run.params.segment.maskLabel = maskLabel;
        if (*rectumOpt) applyParamsJson(run.params, {{"centerline", {{"rectum_mm", rectumMm}}}}, "--rectum-mm");
        if (*stepOpt) run.params.centerline.stepMm = stepMm;
        if (run.ctPath.empty() && run.maskPath.empty())
            throw ParameterError("run: give a CT scan, --mask FILE, or both");
        run.log = &runLog;
        const auto t0 = std::chrono::steady_clock::now();
        const auto manifest = runPipeline(run);
        int computed = 0;
        for (const auto& s : manifest["stages"]) computed += s.value("computed", false) ? 1 : 0;
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        log("study " + fs::absolute(run.studyDir).string() + ": " + std::to_string(computed) + " of " +
            std::to_string(manifest["stages"].size()) + " stages computed, " + std::to_string(s).substr(0, 5) + " s");
        for (const auto& note : studyReviewNotes(manifest)) log("warning: the study needs review: " + note);
        return 0;
    }
};

/// `flyover inspect`: industrial CT of a solid part (inspect/inspect_study.h).
struct InspectCommand {
    CLI::App* inspectCmd = nullptr;
    InspectRunOptions inspect;
    std::vector<std::string> inspectAssignments;
    std::string inspectConfig;
    double inspectThreshold = 0, inspectVoxelMm = 0;
    CLI::Option* thresholdOpt = nullptr;
    CLI::Option* inspectVoxelOpt = nullptr;

    void define(CLI::App& app)
    {
        inspectCmd = app.add_subcommand("inspect", "industrial CT of a solid part: ingest -> voids (pores, cracks) -> "
                                                         "surfaces -> OST overviews and turntable, into a study folder");
        inspectCmd->add_option("ct", inspect.ctPath, "CT scan of the part (NIfTI, NRRD, MetaImage, DICOM; any scalar "
                                                     "grey values, e.g. uint16)")->required();
        inspectCmd->add_option("--study", inspect.studyDir, "study folder for artifacts and manifest.json")->required();
        thresholdOpt = inspectCmd->add_option("--threshold", inspectThreshold, "material is grey value >= this "
                                                                                     "(default: Otsu's threshold)");
        inspectVoxelOpt = inspectCmd->add_option("--voxel-mm", inspectVoxelMm, "isotropic voxel size in mm "
                                                                                     "(default: the smallest input spacing)")
                                    ->check(CLI::PositiveNumber);
        inspectCmd->add_option("--config", inspectConfig, "JSON or TOML file {\"stage\": {\"param\": value}} (see 'flyover params')");
        inspectCmd->add_option("--set", inspectAssignments, "stage.param=value (repeatable; inspect stages: ingest, voids, "
                                                            "surfaces, render; see 'flyover params')");
        inspectCmd->add_option("--until", inspect.untilStage, "run only this stage and what it needs (ingest, voids, surfaces, "
                                                              "overviews, turntable; render = both render steps)");
        inspectCmd->add_option("--force", inspect.forceStage, "recompute this stage and everything downstream");
        inspectCmd->add_flag("--wait", inspect.waitForLock, "wait for another run on the same study instead of refusing");
        inspectCmd->add_option("--cache-max-gb", inspect.cacheMaxGb, "cap on the study's cache")->capture_default_str();
    }

    int execute(RunLog& runLog, const Log& log)
    {
        if (!inspectConfig.empty())
            applyInspectParamsJson(inspect.params, readConfigFile(inspectConfig), inspectConfig);
        for (const auto& a : inspectAssignments) applyInspectAssignment(inspect.params, a);
        if (*thresholdOpt) {
            if (!std::isfinite(inspectThreshold)) throw ParameterError("--threshold: must be finite");
            inspect.params.voids.threshold = inspectThreshold;
        }
        if (*inspectVoxelOpt) inspect.params.ingest.voxelMm = inspectVoxelMm;
        inspect.log = &runLog;
        const auto t0 = std::chrono::steady_clock::now();
        const auto manifest = runInspect(inspect);
        int computed = 0;
        for (const auto& s : manifest["stages"]) computed += s.value("computed", false) ? 1 : 0;
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        log("study " + fs::absolute(inspect.studyDir).string() + ": " + std::to_string(computed) + " of " +
            std::to_string(manifest["stages"].size()) + " stages computed, " + std::to_string(s).substr(0, 5) + " s");
        return 0;
    }
};

/// `flyover status` and `flyover clean`.
struct StatusCommand {
    CLI::App* statusCmd = nullptr;
    StudyStatusOptions status;
    std::vector<std::string> statusAssignments;
    std::string statusConfig;
    CLI::App* cleanCmd = nullptr;
    std::string cleanDir;

    void define(CLI::App& app)
    {
        statusCmd = app.add_subcommand("status", "list each stage of a study as fresh, stale or missing, and why");
        statusCmd->add_option("--study", status.studyDir, "study folder")->required();
        statusCmd->add_option("--ct", status.ctPath, "compare against this scan (default: the one recorded in the manifest)");
        statusCmd->add_option("--config", statusConfig, "parameters as 'run' would take them (default: those of the last run)");
        statusCmd->add_option("--set", statusAssignments, "stage.param=value, as for 'run'");
        cleanCmd = app.add_subcommand("clean", "remove a study's artifacts, manifest and cache");
        cleanCmd->add_option("--study", cleanDir, "study folder")->required();
    }

    int runStatus(RunLog& runLog, const Log& log)
    {
        // Applied by studyStatus: a part study's sections are inspect's.
        StatusParamText text;
        if (!statusConfig.empty()) text.config = readConfigFile(statusConfig);
        text.configSource = statusConfig;
        text.assignments = statusAssignments;
        for (const auto& st : studyStatus(status, text))
            std::cout << st.stage << std::string(12 - std::min<std::size_t>(11, st.stage.size()), ' ') << st.state
                      << (st.reason.empty() ? "" : "  (" + st.reason + ")") << "\n";
        for (const auto& note : studyReviewNotes(status.studyDir)) std::cout << "needs review: " << note << "\n";
        return 0;
    }

    int runClean(RunLog& runLog, const Log& log)
    {
        cleanStudy(cleanDir);
        log("study " + cleanDir + " cleaned");
        return 0;
    }
};

/// `flyover export`: a study's results in formats other tools load.
struct ExportCommand {
    CLI::App* exportCmd = nullptr;
    std::string exportStudy, exportMeshPath;
    std::string exportLumenPath, exportCenterlinePath;

    void define(CLI::App& app)
    {
        exportCmd = app.add_subcommand("export", "write a study's results in formats other tools load");
        exportCmd->add_option("--study", exportStudy, "study folder")->required();
        exportCmd->add_option("--mesh", exportMeshPath, "lumen surface as .ply, .obj, .stl or .off (inward normals)");
        exportCmd->add_option("--centerline", exportCenterlinePath, "centerline as a 3D Slicer markups curve (.mrk.json) or "
                                                                    "VTK polyline (.vtk), LPS mm, bridged points marked");
        exportCmd->add_option("--lumen", exportLumenPath, "lumen mask (uint8, 1 inside) on the original scan's grid "
                                                          "and geometry: .nii.gz, .nii, .nrrd or .mha");
    }

    int execute(RunLog& runLog, const Log& log)
    {
        bool any = false;
        if (!exportMeshPath.empty()) {
            exportMesh(exportStudy, exportMeshPath);
            log("surface written to " + exportMeshPath);
            any = true;
        }
        if (!exportLumenPath.empty()) {
            exportLumen(exportStudy, exportLumenPath);
            log("lumen mask written to " + exportLumenPath);
            any = true;
        }
        if (!exportCenterlinePath.empty()) {
            exportCenterline(exportStudy, exportCenterlinePath);
            log("centerline written to " + exportCenterlinePath);
            any = true;
        }
        if (!any) throw ParameterError("export: name at least one output (--mesh, --lumen, --centerline)");
        return 0;
    }
};

/// `flyover view`: the interactive viewer.
struct ViewCommand {
    CLI::App* viewCmd = nullptr;
    std::string viewStudy, viewCt;
    int viewPort = 0;

    void define(CLI::App& app)
    {
        viewCmd = app.add_subcommand("view", "interactive viewer: a local web page (127.0.0.1, token in the URL) "
                                                   "flying over a study; Ctrl-C stops it");
        viewCmd->add_option("--study", viewStudy,
                            "study folder (after flyover run, or while it runs: the page shows the study as soon as "
                            "its first pair is out and follows it)")
            ->required();
        viewCmd->add_option("--port", viewPort, "port on 127.0.0.1 (0 = a free one)")->check(CLI::Range(0, 65535));
        viewCmd->add_option("--ct", viewCt, "CT for the slices when the study has no ct.vdb (a mask-only study)");
    }

    int execute(RunLog& runLog, const Log& log)
    {
        return runViewCommand(viewStudy, viewPort, viewCt, std::cout);
    }
};

/// `flyover report`: the exam's C-RADS report (colon/report.h).
struct ReportCommand {
    CLI::App* reportCmd = nullptr;
    std::string reportStudy;

    void define(CLI::App& app)
    {
        reportCmd = app.add_subcommand("report", "write DIR/report/ (report.json, report.html): the C-RADS category from "
                                                 "the accepted findings (before any review: a draft from the "
                                                 "candidates of 6 mm or more) and the exam's coverage");
        reportCmd->add_option("--study", reportStudy, "study folder (after flyover run with its coverage and polyps "
                                                      "stages)")
            ->required();
    }

    int execute(RunLog& runLog, const Log& log)
    {
        const auto report = writeReport(reportStudy);
        log("report " + (fs::path(reportStudy) / "report" / "report.html").string() + ": " +
            report["c_rads"].get<std::string>() + (report["draft"].get<bool>() ? " (draft: no finding reviewed yet)" : "") +
            ", " + std::to_string(report["findings"].size()) + " finding(s)");
        return 0;
    }
};

/// `flyover stage`: one stage, for workflow engines (pipeline/stage_command.h for the exit codes).
struct StageCommand {
    CLI::App* stageCmd = nullptr;
    StageCommandOptions stageOpt;
    std::vector<std::string> stageAssignments;
    std::string stageConfig;

    void define(CLI::App& app)
    {
        stageCmd = app.add_subcommand("stage", "run one stage from the study's existing results (upstream stages must be "
                                                     "fresh); writes DIR/stages/NAME.json; exit 1 bad input, 2 bad parameter, "
                                                     "4 upstream not ready, 75 temporary failure (retry)");
        stageCmd->add_option("name", stageOpt.stage, "ingest, segment, centerline, mesh or render; a part study's "
                                                      "(flyover inspect): inspect:ingest, inspect:voids, inspect:surfaces, "
                                                      "inspect:overviews, inspect:turntable (the prefix may be left out "
                                                      "once the study exists)")->required();
        stageCmd->add_option("--study", stageOpt.studyDir, "study folder")->required();
        stageCmd->add_option("--ct", stageOpt.ctPath, "CT scan (default: the one recorded in the study)");
        stageCmd->add_option("--mask", stageOpt.maskPath, "lumen mask (default: the one recorded in the study, if any)");
        stageCmd->add_option("--config", stageConfig, "parameters as 'run' takes them");
        stageCmd->add_option("--set", stageAssignments, "stage.param=value, as for 'run' (this stage's and those upstream)");
        stageCmd->add_flag("--wait", stageOpt.waitForLock, "wait for another run on the same study instead of exiting 75");
        stageCmd->add_option("--cache-max-gb", stageOpt.cacheMaxGb, "cap on the study's cache")->capture_default_str();
    }

    int execute(RunLog& runLog, const Log& log)
    {
        resolveStagePipeline(stageOpt);  // inspect:NAME, or a part study's manifest: inspect's parameters
        if (!stageConfig.empty()) stageOpt.params->applyJson(readConfigFile(stageConfig), stageConfig);
        for (const auto& a : stageAssignments) stageOpt.params->applyAssignment(a);
        stageOpt.log = &runLog;
        const auto receipt = runStageCommand(stageOpt);
        log("study " + fs::absolute(stageOpt.studyDir).string() + ": " + stageOpt.stage + " " +
            (receipt.value("computed", false) ? "computed" : "reused"));
        return 0;
    }
};

/// `flyover params`: every stage parameter with its default.
struct ParamsCommand {
    CLI::App* paramsCmd = nullptr;

    void define(CLI::App& app)
    {
        paramsCmd = app.add_subcommand("params", "list every stage parameter with its default");
    }

    int execute(RunLog& runLog, const Log& log)
    {
        std::cout << "Stage parameters (set with --set stage.param=value or --config FILE):\n"
                  << describeParams()
                  << "\nflyover inspect's stage parameters (same syntax, for 'flyover inspect'):\n"
                  << describeInspectParams();
        return 0;
    }
};

} // namespace

int main(int argc, char** argv)
{
    CLI::App app{"flyover: CT scan -> colon lumen -> centerline -> surface -> one-sided-transparency "
                 "(OST) fly-over images.\nWorld coordinates are LPS millimetres (as in DICOM and ITK) "
                 "in every artifact."};
    app.require_subcommand(1);
    // Global options are accepted after the subcommand too ("flyover run CT --study S --log-json"):
    // a subcommand hands the options it does not know to the app (inherited by every subcommand).
    app.fallthrough();
    app.set_version_flag("--version", "flyover 0.1.0");
    int threads = 0;
    app.add_option("--threads", threads, "worker threads (0 = all cores)")->check(CLI::NonNegativeNumber);
    bool quiet = false, logJson = false;
    app.add_flag("-q,--quiet", quiet, "no progress output on stderr");
    app.add_flag("--log-json", logJson, "progress as JSON lines on stderr (for scripts)");

    PhantomCommand phantom;
    phantom.define(app);
    RunCommand runCommand;
    runCommand.define(app);
    InspectCommand inspectCommand;
    inspectCommand.define(app);
    StatusCommand status;
    status.define(app);
    ExportCommand exportCommand;
    exportCommand.define(app);
    ViewCommand view;
    view.define(app);
    StageCommand stage;
    stage.define(app);
    ParamsCommand params;
    params.define(app);
    ReportCommand report;
    report.define(app);

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
        // The applications whose studies status, stage and clean open.
        registerStudyPipeline(colonPipeline());
        registerStudyPipeline(inspectPipeline());
        if (*params.paramsCmd) return params.execute(runLog, log);
        if (*phantom.phantomCmd) return phantom.execute(runLog, log);
        if (*runCommand.runCmd) return runCommand.execute(runLog, log);
        if (*inspectCommand.inspectCmd) return inspectCommand.execute(runLog, log);
        if (*status.statusCmd) return status.runStatus(runLog, log);
        if (*exportCommand.exportCmd) return exportCommand.execute(runLog, log);
        if (*view.viewCmd) return view.execute(runLog, log);
        if (*stage.stageCmd) return stage.execute(runLog, log);
        if (*report.reportCmd) return report.execute(runLog, log);
        if (*status.cleanCmd) return status.runClean(runLog, log);
    } catch (const std::exception& e) {
        // 1 bad input, 2 bad parameter, 3 busy study, 4 upstream not ready, 75 retry (stage_command.h)
        const int code = exitCodeFor(std::current_exception());
        if (*stage.stageCmd) {
            writeFailedReceipt(stage.stageOpt.studyDir, stage.stageOpt.stage, e.what(), code);
            return fail(e.what(), code == EXIT_STUDY_BUSY ? EXIT_TEMPFAIL : code);
        }
        return fail(e.what(), code);
    }
    return 0;
}
