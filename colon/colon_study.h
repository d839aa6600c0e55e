/// @file colon_study.h
/// @brief The colon's study (`flyover run`): ingest -> segment -> {centerline, mesh} -> frames
///        -> {flythrough, overviews, video, coverage} (the render steps), its stage table for
///        the engine (pipeline/study.h), and the options and status of a colon study.
///
/// Artifacts:
///   ct.vdb           FloatGrid "ct_hu" (HU, LPS mm transform, outside air inactive)
///   lumen.vdb        BoolGrid "lumen_mask" and FloatGrid "lumen_sdf" (mm, negative inside)
///   centerline.json  schema flyover.centerline/1
///   surface.ply      binary PLY, faces wound so that normals point into the lumen
///   frames/          pair_NNNN.png (camera 0 | camera 1) and poses.json
///   flythrough/      fly-through pairs (forward | backward) and poses.json
///   overview.png     OST of the whole colon from outside (anterior view); overviews/ the six views
///   video/           flyover.mp4 and its poses.json
///   coverage/        coverage.json, surface_seen.ply
#pragma once

#include "colon/params.h"
#include "pipeline/param_set.h"
#include "pipeline/study.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// The colon's parameters as the engine sees them.
using ColonParamSet = ParamSetOf<PipelineParams, stageNames, stageParamsToJson, stageVersion, validateParams,
                                 applyParamsJson, applyParamAssignment>;

/// A colon run: the engine's options and the colon's parameters.
struct RunOptions : StudyOptions {
    PipelineParams params;
};

/// The colon's stage table (registered with the engine on first use).
const StudyPipeline& colonPipeline();

/// Runs what is stale of the colon's graph; returns the manifest written to DIR/manifest.json.
/// @throw StageError naming the failing stage; InputError/ParameterError/StudyBusy before any stage.
nlohmann::json runPipeline(const RunOptions& options);

/// `flyover status` of a colon study with these parameters (paramsGiven), or the last run's.
struct StatusOptions {
    std::string studyDir;
    std::string ctPath;           ///< "" = the input recorded in the manifest
    std::string maskPath;         ///< "" = the mask recorded in the manifest (if any)
    PipelineParams params;
    bool paramsGiven = false;     ///< false: compare with the parameters of the last run
};
std::vector<StageStatus> studyStatus(const StatusOptions& options);

/// Stage names of the colon's graph upstream of `stage` (downstream of it), inclusive, in order.
std::vector<std::string> stagesNeededFor(const std::string& stage);
std::vector<std::string> stagesAffectedBy(const std::string& stage);

} // namespace flyover
