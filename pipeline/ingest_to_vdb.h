/// @file ingest_to_vdb.h
/// @brief The ingest every application's stage graph shares: the scan into an isotropic grid
///        and ct.vdb.
#pragma once

#include "pipeline/stage_run.h"
#include "volume/image_io.h"
#include "volume/ingest.h"
#include "volume/progress.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>

#include <functional>
#include <string>

namespace flyover {

/// Reads run.options.ctPath into an isotropic grid named `gridName`, writes it to ct.vdb and
/// returns the ingest report (geometry, reader, warnings). `beforeWrite`, when given, is called
/// with the grid before ct.vdb is written.
nlohmann::json ingestToCtVdb(StageRun& run, const IngestParams& params, const ImageReadOptions& options,
                             const std::string& gridName, Progress* progress, openvdb::FloatGrid::Ptr& grid,
                             const std::function<void(const openvdb::FloatGrid::Ptr&)>& beforeWrite = {});

} // namespace flyover
