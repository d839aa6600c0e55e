/// @file part_phantom_io.h
/// @brief `flyover phantom --part`: writes the industrial part phantom (inspect/part_phantom.h)
///        slice by slice (volume/slab_writer.h: .nii, .nii.gz or .nrrd, uint16) and its truth
///        JSON (schema flyover.part_truth/1, LPS mm).
#pragma once

#include "inspect/part_phantom.h"

#include <nlohmann/json.hpp>

#include <string>

namespace flyover {

nlohmann::json partTruthToJson(const PartTruth& truth);

/// Parses `--size` for `--part`: a whole number of voxels (96..2048).
/// @throw ParameterError naming --size
int parsePartSize(const std::string& text);

/// Writes the CT (streamed: memory for a few slices) and then the truth; both atomically.
/// @throw ParameterError / InputError naming the parameter or file
PartTruth writePartPhantom(const PartPhantomParams& params, const std::string& ctPath,
                           const std::string& truthPath, Progress* progress = nullptr);

} // namespace flyover
