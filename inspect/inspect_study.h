/// @file inspect_study.h
/// @brief A part study (`flyover inspect`): ingest -> voids -> surfaces -> {overviews,
///        turntable}, its stage table for the engine (pipeline/study.h), its run context and
///        its stage bodies (stage_inspect.cpp). The manifest of a part study says
///        "pipeline": "inspect".
#pragma once

#include "inspect/inspect_params.h"
#include "pipeline/param_set.h"
#include "pipeline/stage_run.h"
#include "pipeline/study.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>

#include <memory>

namespace flyover {

class Progress;
struct PartAnalysis;
struct PartSurface;

/// Inspect's parameters as the engine sees them.
using InspectParamSet = ParamSetOf<InspectParams, inspectSections, inspectParamsToJson, inspectSectionVersion,
                                   validateInspectParams, applyInspectParamsJson, applyInspectAssignment>;

/// A part study's run: the engine's options and inspect's parameters.
struct InspectRunOptions : StudyOptions {
    InspectParams params;
};

/// The inspect stage table (registered with the engine on first use).
const StudyPipeline& inspectPipeline();

/// Runs what is stale of a part study; returns the manifest.
/// @throw StageError naming the failing stage; InputError/ParameterError/StudyBusy before any stage.
nlohmann::json runInspect(const InspectRunOptions& options);

/// Objects handed from stage to stage in memory within one part run.
struct PartState {
    openvdb::FloatGrid::Ptr hu;
    std::shared_ptr<PartAnalysis> part;          ///< the voids stage's analysis
    std::shared_ptr<PartSurface> partSurface;    ///< the surfaces stage's mesh
};

struct InspectParamsHolder {
    explicit InspectParamsHolder(const InspectParams& p) : paramSet(p) {}
    InspectParamSet paramSet;
};

/// What an inspect stage body sees of a run.
class PartRun : private InspectParamsHolder, public StageRun {
public:
    explicit PartRun(const InspectRunOptions& o) : InspectParamsHolder(o.params), StageRun(o, paramSet), opt(o) {}
    const InspectRunOptions& opt;
    PartState state;
};

// The stage bodies (stage_inspect.cpp): each writes its artifacts and returns its report.
nlohmann::json runPartIngest(PartRun& run, Progress* progress);
nlohmann::json runVoids(PartRun& run, Progress* progress);
nlohmann::json runPartSurfaces(PartRun& run, Progress* progress);
nlohmann::json runPartOverviews(PartRun& run, Progress* progress);
nlohmann::json runTurntable(PartRun& run, Progress* progress);

} // namespace flyover
