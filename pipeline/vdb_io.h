/// @file vdb_io.h
/// @brief .vdb artifacts: grids written atomically with deterministic bytes, read by name.
#pragma once

#include <openvdb/openvdb.h>

#include <string>

namespace flyover {

/// Writes grids to a compressed .vdb file (readable by vdb_print).
void writeGrids(const std::string& path, const openvdb::GridPtrVec& grids);
/// Reads one named grid. @throw InputError naming the file and grid.
openvdb::GridBase::Ptr readGrid(const std::string& path, const std::string& gridName);
/// The same with OpenVDB's delayed loading: the tree's topology is read now, each leaf's values
/// only when first accessed (from the file, kept open; a study's files are replaced by rename,
/// never rewritten in place). For a caller that reads a small part of a large grid's values
/// (the part surfaces: a narrow band around the surfaces of a 1024^3 CT).
openvdb::GridBase::Ptr readGridDelayed(const std::string& path, const std::string& gridName);

} // namespace flyover
