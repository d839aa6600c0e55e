/// @file stage_command.h
/// @brief `flyover stage NAME --study DIR`: one stage of a study, for workflow engines
///        (Snakemake, SLURM arrays, Nextflow). The stage runs from the study's existing
///        results: every stage upstream of it must be fresh for the given inputs and
///        parameters, else it refuses (it never recomputes upstream work behind the engine's
///        back). Each call leaves a receipt DIR/stages/NAME.json that a workflow names as the
///        rule's output:
///
///     {"schema": "flyover.stage/1", "stage": NAME, "status": "ok" | "failed",
///      "error": one line (failed only), "exit_code": 0 | 1 | 2, "computed": bool,
///      "keys": {stage or step: cache key}, "outputs": {artifact: digest}, "wall_seconds": s,
///      "world_frame": "LPS"}
/// ("keys" and "outputs" cover every cached step of a stage that has several, e.g. render's.)
///
/// Exit codes (also those of `flyover run`, which keeps 3 for a busy study):
///   0   done (computed or reused)                                 receipt "ok"
///   1   bad input: the scan, mask or an upstream stage's data is unusable, or an upstream
///       stage already failed on it. Do not retry.                  receipt "failed"
///   2   bad parameter (unknown name, out of range). Do not retry.  receipt "failed" when the
///       command line itself parsed (a per-scan option), none otherwise
///   4   not ready: an upstream stage is missing or stale; run it first.   no receipt
///   75  temporary failure (EX_TEMPFAIL): disk full, I/O error, out of memory, study locked
///       by another run (without --wait). Worth retrying.           no receipt
/// A receipt left by an earlier call is removed first, so a killed or retryable run never
/// leaves an "ok" receipt that a later rule trusts.
#pragma once

#include "pipeline/param_set.h"
#include "pipeline/run_log.h"
#include "pipeline/study.h"

#include <exception>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

namespace flyover {

inline constexpr int EXIT_BAD_INPUT = 1;
inline constexpr int EXIT_BAD_PARAMETER = 2;
inline constexpr int EXIT_STUDY_BUSY = 3;  ///< `flyover run` only
inline constexpr int EXIT_NOT_READY = 4;
inline constexpr int EXIT_TEMPFAIL = 75;   ///< sysexits.h EX_TEMPFAIL

/// An upstream stage is missing or stale: the stage cannot run yet (exit 4).
struct StageNotReady : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct StageCommandOptions {
    /// A stage of the study's table: one of its commandStages, with its table's stagePrefix
    /// ("inspect:voids") or without it for the table whose prefix is "" (resolveStagePipeline
    /// strips it).
    std::string stage;
    std::string studyDir;
    std::string ctPath;           ///< "" = the scan recorded in the study's manifest
    std::string maskPath;         ///< "" = the mask recorded in the manifest (if any)
    const StudyPipeline* pipeline = nullptr;  ///< set by resolveStagePipeline
    /// Parameters of this stage and of those upstream, of the pipeline's kind (set to its
    /// defaults by resolveStagePipeline).
    std::unique_ptr<ParamSet> params;
    bool waitForLock = false;     ///< wait for a concurrent run instead of exiting 75
    double cacheMaxGb = 20.0;
    RunLog* log = nullptr;
};

/// Sets `pipeline` (and `params` to its defaults) from the registered tables and strips the
/// table's prefix from `stage`: the table whose prefix the name starts with, else the one a
/// study's manifest names, else the one without a prefix. Call it before applying
/// --set/--config (a part study takes inspect's parameters).
void resolveStagePipeline(StageCommandOptions& options);

/// Runs one stage (see the file comment) and writes its "ok" receipt.
/// @return the receipt.
/// @throw StageNotReady, InputError, ParameterError, StageError, StudyBusy, TransientError.
nlohmann::json runStageCommand(const StageCommandOptions& options);

/// Writes the "failed" receipt of a stage whose run threw `error` with exit code `exitCode`
/// (1 or 2), creating the study folder if needed; does nothing for other codes or an unknown
/// stage name. Never throws.
void writeFailedReceipt(const std::string& studyDir, const std::string& stage, const std::string& error,
                        int exitCode) noexcept;

/// The exit code for an exception escaping a command: 75 when its cause (nested causes
/// included) says the machine failed (TransientError, out of memory, an errno such as ENOSPC
/// or EIO), else 1 (bad input), 2 (ParameterError), 3 (StudyBusy), 4 (StageNotReady).
int exitCodeFor(const std::exception_ptr& error);

/// Path of a stage's receipt in a study: DIR/stages/NAME.json.
std::string receiptPath(const std::string& studyDir, const std::string& stage);

/// A path the study's manifest records under `key` ("input": the CT, "mask": the lumen mask);
/// "" when it records none (a mask-only study's "input" is null).
std::string recordedInput(const nlohmann::json& manifest, const char* key);

} // namespace flyover
