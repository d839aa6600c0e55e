/// @file study.h
/// @brief The engine: a study folder filled by an application's stage table, run as a TBB flow
///        graph (a node per stage, an edge per upstream stage), each stage cached by a key over
///        (stage, version, the parameters it depends on, input digests). The engine knows no
///        application: each hands its table (StudyPipeline) and its run context (StageRun) to
///        runStudy, and registers its table for the commands that open an existing study
///        (status, stage, clean). "render" names all render steps in --until and --force.
///
/// Every artifact is written atomically and kept content-addressed under DIR/.flyover/;
/// manifest.json records per stage: key, version, parameters, input/output digests, wall time,
/// computed or reused, report.
#pragma once

#include "pipeline/param_set.h"
#include "pipeline/run_log.h"

#include <nlohmann/json.hpp>

#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace flyover {

class StageRun;
class Progress;

/// A stage failed; what() names the stage and the cause.
struct StageError : std::runtime_error {
    StageError(const std::string& stage, const std::string& cause)
        : std::runtime_error(stage + ": " + cause), stageName(stage) {}
    std::string stageName;
};

/// What a run is asked to do, for any application.
struct StudyOptions {
    std::string ctPath;           ///< the input scan (file or DICOM directory); "" with a mask alone
    /// An external lumen mask or label map, read by the stage that takes it (StageSpec::takesMask)
    /// instead of the CT's air. Without a CT (ctPath "") the stages reading the scan are skipped.
    std::string maskPath;
    std::string studyDir;         ///< output folder (created if missing)
    std::string untilStage;       ///< run only this stage and what it needs ("" = all)
    std::string forceStage;       ///< recompute this stage and everything downstream
    bool waitForLock = false;     ///< wait for a concurrent run instead of refusing
    double cacheMaxGb = 20.0;     ///< cap on the study's cache; least recently used evicted
    RunLog* log = nullptr;        ///< progress and messages (null: silent)
};

/// A stage table row: a stage, the stages upstream of it, the artifacts it reads and writes,
/// its body (returning the report for the manifest) and what its key covers.
struct StageSpec {
    std::string name;
    std::vector<std::string> upstream;  ///< stages whose outputs this stage reads
    std::vector<std::string> inputs;    ///< artifact names read ("input" = the scan)
    std::vector<std::string> outputs;   ///< artifact names written
    std::function<nlohmann::json(StageRun&, Progress*)> body;
    /// The parameter section the stage takes its parameters from ("" = its own name), and the
    /// names it depends on (empty = all of them): a render step is keyed by its own subset of
    /// render.*, so that changing render.video_fps recomputes the video only.
    std::string paramStage = "";
    std::vector<std::string> paramNames = {};
    /// Steps that run first when both run (order only: no data passes, no key depends on it).
    std::vector<std::string> after = {};
    /// Write-behind: the next stages start as soon as the body returns (they take its results
    /// from memory); the fsync and rename of its artifacts and its cache record follow beside
    /// them. The artifacts are hashed before, in their temporaries, so that keys stay content
    /// digests.
    bool writeBehind = false;
    /// The stage that reads the run's --mask (its digest "mask" among its inputs; alone, without
    /// a CT).
    bool takesMask = false;
    /// Of the stages ready at once, those of higher priority start first (TBB flow graph node
    /// priority; order only; 0 = none).
    unsigned priority = 0;
    /// Artifacts read as well when the study has a CT (its key then covers them), from their
    /// files: the stage starts after the commit of a write-behind stage that writes them.
    std::vector<std::string> inputsWithCt = {};
    /// Parameters of other sections the stage depends on as well ("section.name").
    std::vector<std::string> otherParams = {};
};

/// Work that starts ahead of the stage it feeds, as soon as a result it reads is in memory: a
/// node of the graph with an edge from that hand-on (StageRun::handOn, "<stage>:<result>")
/// and edges to the stages that take its result from the run's state. Not cached, not in the
/// manifest: the stage it feeds records what it took. It runs when a stage it feeds is wanted.
struct EarlySpec {
    std::string name;
    std::string reads;               ///< the hand-on it starts on
    std::vector<std::string> feeds;  ///< the stages that wait for it
    std::function<void(StageRun&, Progress*)> body;
};

/// An application's stage graph, as it hands it to the engine.
struct StudyPipeline {
    std::string name;                   ///< "colon", "inspect"
    /// The manifest's "pipeline" value of its studies ("" = none written: the default kind).
    std::string manifestName;
    /// The prefix of its stage names in `flyover stage` ("" for the default kind, "inspect:").
    std::string stagePrefix;
    /// What its studies are called in messages: "colon (flyover run)".
    std::string studyWord;
    std::vector<StageSpec> stages;      ///< in pipeline order; the first has no upstream
    std::vector<EarlySpec> early;
    /// The hand-on the write-behind's commits (fsync, rename, record) wait for ("" = none: they
    /// follow their stage at once).
    std::string commitsAfter;
    /// The names `flyover stage` takes (a parameter section such as "render" runs its steps).
    std::vector<std::string> commandStages;
    /// How a missing study folder is started, for the message of `flyover stage`.
    std::string firstStageHint;
    /// Its parameters at their defaults.
    std::function<std::unique_ptr<ParamSet>()> defaultParams;
    /// Runs the application's graph on these options and parameters (its run context built
    /// over them): what `flyover stage` calls.
    std::function<nlohmann::json(const StudyOptions&, const ParamSet&)> run;
};

/// The stage tables of the applications, for the commands that open an existing study. Each
/// application registers its table once (the command line registers every one it offers).
void registerStudyPipeline(const StudyPipeline& pipeline);
const std::vector<const StudyPipeline*>& studyPipelines();
/// The table a study's manifest names ("pipeline"; absent: the one registered with manifestName "").
/// @throw InputError when no registered table has that name.
const StudyPipeline& studyPipelineOf(const nlohmann::json& manifest);

/// Runs what is stale of `pipeline` on `run` (its options, its parameters, its state); returns
/// the manifest written to DIR/manifest.json.
/// @throw StageError naming the failing stage; InputError/ParameterError/StudyBusy before any stage.
nlohmann::json runStudy(const StudyPipeline& pipeline, StageRun& run);

struct StageStatus {
    std::string stage;
    std::string state;   ///< "fresh", "stale", "missing", or "unused" (ingest of a mask-only study)
    std::string reason;  ///< why, for stale and missing
};

/// `flyover status --config/--set` as given on the command line: applied to the study's own
/// kind of parameters.
struct StatusParamText {
    nlohmann::json config;                 ///< null: none
    std::string configSource;
    std::vector<std::string> assignments;
};

struct StudyStatusOptions {
    std::string studyDir;
    std::string ctPath;           ///< "" = the input recorded in the manifest
    std::string maskPath;         ///< "" = the mask recorded in the manifest (if any)
    /// The parameters to compare with (of the study's kind); null: those of the last run, or
    /// the defaults with `text` applied when `text` gives any.
    const ParamSet* params = nullptr;
};

/// What a run would do with these options, stage by stage, and why. Without given parameters
/// the last run's are used: each stage's recorded ones, else the manifest's "parameters" (a
/// killed run's stages that never finished).
/// @throw InputError when DIR is not a study; ParameterError for a bad --set/--config.
std::vector<StageStatus> studyStatus(const StudyStatusOptions& options, const StatusParamText& given = {});

/// What the stages of a study flagged for a reader's review (each stage report's "needs_review"
/// strings, as "stage: why"), in stage order: a run that finished but may be wrong (the path's
/// start far above the lowest lumen point, say). Empty for a study without a manifest.
std::vector<std::string> studyReviewNotes(const std::string& studyDir);
std::vector<std::string> studyReviewNotes(const nlohmann::json& manifest);

/// Removes every artifact (of every registered table), the manifest and the cache of a study
/// (takes the lock).
void cleanStudy(const std::string& studyDir);

/// Copies a study for work that must not touch it (benchmarks, experiments): the manifest,
/// the artifacts and the cache records are copied, the cache objects hard-linked (nothing
/// ever writes an object in place: every writer renames a new file over the old name).
/// `to` must not exist. @throw InputError when `from` is not a study or `to` exists.
void copyStudy(const std::string& from, const std::string& to);

/// Stage names upstream of `stage`, inclusive, in pipeline order.
std::vector<std::string> stagesNeededFor(const StudyPipeline& pipeline, const std::string& stage);
/// Stage names downstream of `stage`, inclusive, in pipeline order.
std::vector<std::string> stagesAffectedBy(const StudyPipeline& pipeline, const std::string& stage);

} // namespace flyover
