/// @file grid_write.h
/// @brief writeGrids (artifact_io.h) with a choice of value compression.
#pragma once

#include <openvdb/openvdb.h>

#include <string>

namespace flyover {

/// How a .vdb's values are stored: inactive voxels are always left out; active values with
/// Blosc (LZ4) or raw. Blosc compresses each leaf twice (once to size it for delayed
/// loading): on CT noise it saves ~15% of ct.vdb for ~1 s of CPU on the full phantom
/// (bench/ingest_profile), so ct.vdb is written raw.
enum class VdbValues { Blosc, Raw };

/// writeGrids(path, grids) with the given value compression (Blosc there).
void writeGrids(const std::string& path, const openvdb::GridPtrVec& grids, VdbValues values);

/// The bytes io::File::write writes (but in 1 MB writes: io::File's stream makes a write() per
/// leaf), straight into `file` (no temporary, OpenVDB's random UUID): writeGrids' writer.
/// @throw std::system_error with the errno of a failed open, write, seek or close.
void writeVdbFile(const std::string& file, const openvdb::GridPtrVec& grids, VdbValues values);

} // namespace flyover
