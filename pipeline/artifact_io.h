/// @file artifact_io.h
/// @brief On-disk artifacts of a study, every family: atomic writes, digests, JSON, VDB, PLY
///        and PNG (include the one a file needs; this header gathers them).
#pragma once

#include "pipeline/atomic_write.h"
#include "pipeline/crash_point.h"
#include "pipeline/digests.h"
#include "pipeline/json_io.h"
#include "pipeline/ply_io.h"
#include "pipeline/png_io.h"
#include "pipeline/vdb_io.h"
