/// @file study.h
/// @brief A study folder and the stages that fill it: ingest -> segment -> {centerline,
///        mesh} -> frames -> {flythrough, overviews, video, coverage} (the render steps), run as
///        a TBB flow graph (centerline and mesh side by side, the render steps after the frames
///        side by side), each stage cached by a key over (stage, version, the parameters it
///        depends on, input digests). "render" names all render steps in --until and --force.
///
/// Artifacts (all written atomically, all kept content-addressed under DIR/.flyover/):
///   ct.vdb           FloatGrid "ct_hu" (HU, LPS mm transform, outside air inactive)
///   lumen.vdb        BoolGrid "lumen_mask" and FloatGrid "lumen_sdf" (mm, negative inside)
///   centerline.json  schema flyover.centerline/1
///   surface.ply      binary PLY, faces wound so that normals point into the lumen
///   frames/          pair_NNNN.png (camera 0 | camera 1) and poses.json
///   flythrough/      fly-through pairs (forward | backward) and poses.json
///   overview.png     OST of the whole colon from outside (anterior view); overviews/ the six views
///   video/           flyover.mp4 and its poses.json
///   coverage/        coverage.json, surface_seen.ply
///   manifest.json    per stage: key, version, parameters, input/output digests, wall time,
///                    computed or reused, report
#pragma once

#include "inspect/inspect_params.h"
#include "colon/params.h"
#include "pipeline/run_log.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// A stage failed; what() names the stage and the cause.
struct StageError : std::runtime_error {
    StageError(const std::string& stage, const std::string& cause)
        : std::runtime_error(stage + ": " + cause), stageName(stage) {}
    std::string stageName;
};

/// Which stage graph a study runs: the colon's (`flyover run`) or a solid part's
/// (`flyover inspect`: ingest -> voids -> surfaces -> {overviews, turntable}; see
/// inspect/stage_inspect.cpp). The manifest of a part study says "pipeline": "inspect".
enum class StudyKind { Colon, Part };

struct RunOptions {
    StudyKind kind = StudyKind::Colon;
    InspectParams inspect;        ///< the parameters of a part study (kind Part)
    std::string ctPath;           ///< the input scan (file or DICOM directory); "" with a mask alone
    /// An external lumen mask or label map (params.segment.mask_label picks the label): the
    /// segment stage takes the lumen from it instead of from the CT's air. With a CT it is
    /// matched to the CT's grid; without one (ctPath "") ingest is skipped and the lumen keeps
    /// the mask's own geometry.
    std::string maskPath;
    std::string studyDir;         ///< output folder (created if missing)
    PipelineParams params;
    std::string untilStage;       ///< run only this stage and what it needs ("" = all)
    std::string forceStage;       ///< recompute this stage and everything downstream
    bool waitForLock = false;     ///< wait for a concurrent run instead of refusing
    double cacheMaxGb = 20.0;     ///< cap on the study's cache; least recently used evicted
    RunLog* log = nullptr;        ///< progress and messages (null: silent)
};

/// Runs what is stale; returns the manifest written to DIR/manifest.json.
/// @throw StageError naming the failing stage; InputError/ParameterError/StudyBusy before any stage.
nlohmann::json runPipeline(const RunOptions& options);

struct StageStatus {
    std::string stage;
    std::string state;   ///< "fresh", "stale", "missing", or "unused" (ingest of a mask-only study)
    std::string reason;  ///< why, for stale and missing
};

struct StatusOptions {
    std::string studyDir;
    std::string ctPath;           ///< "" = the input recorded in the manifest
    std::string maskPath;         ///< "" = the mask recorded in the manifest (if any)
    PipelineParams params;
    InspectParams inspect;        ///< a part study's given parameters (the base of StatusParamText's)
    bool paramsGiven = false;     ///< false: compare with the parameters of the last run
};

/// `flyover status --config/--set` as given on the command line: applied by the study's kind,
/// to StatusOptions::params for a colon study, to inspect's defaults for a part study.
struct StatusParamText {
    nlohmann::json config;                 ///< null: none
    std::string configSource;
    std::vector<std::string> assignments;
};

/// What `run` (or `inspect`, for a part study) would do with these options, stage by stage,
/// and why. Without given parameters the last run's are used: each stage's recorded ones,
/// else the manifest's "parameters" (a killed run's stages that never finished).
/// @throw InputError when DIR is not a study; ParameterError for a bad --set/--config.
std::vector<StageStatus> studyStatus(const StatusOptions& options, const StatusParamText& given = {});

/// What the stages of a study flagged for a reader's review (each stage report's "needs_review"
/// strings, as "stage: why"), in stage order: a run that finished but may be wrong (the path's
/// start far above the lowest lumen point, say). Empty for a study without a manifest.
std::vector<std::string> studyReviewNotes(const std::string& studyDir);
std::vector<std::string> studyReviewNotes(const nlohmann::json& manifest);

/// Removes every artifact, the manifest and the cache of a study (takes the lock).
void cleanStudy(const std::string& studyDir);

/// Copies a study for work that must not touch it (benchmarks, experiments): the manifest,
/// the artifacts and the cache records are copied, the cache objects hard-linked (nothing
/// ever writes an object in place: every writer renames a new file over the old name).
/// `to` must not exist. @throw InputError when `from` is not a study or `to` exists.
void copyStudy(const std::string& from, const std::string& to);

/// Stage names upstream of `stage`, inclusive, in pipeline order.
std::vector<std::string> stagesNeededFor(const std::string& stage, StudyKind kind = StudyKind::Colon);
/// Stage names downstream of `stage`, inclusive, in pipeline order.
std::vector<std::string> stagesAffectedBy(const std::string& stage, StudyKind kind = StudyKind::Colon);

} // namespace flyover
