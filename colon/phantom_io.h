/// @file phantom_io.h
/// @brief Writes a generated phantom: the CT as NIfTI (int16 HU, correct affine), the truth
///        JSON (schema flyover.phantom-truth/1) and optionally the true lumen mask.
#pragma once

#include "colon/phantom.h"

#include <nlohmann/json.hpp>

#include <string>

namespace flyover {

nlohmann::json phantomTruthToJson(const Phantom& phantom, const PhantomParams& params);

/// Reads back the truth centerline and polyps (for tests and evaluation).
PhantomTruth phantomTruthFromJson(const nlohmann::json& j, const std::string& source);

/// Parses "SX,SY,SZ" (mm) for `flyover phantom --spacing`.
/// @throw ParameterError naming --spacing for anything else (the range is checked by makePhantom)
Vec3d parsePhantomSpacing(const std::string& text);

/// @param maskPath empty: no mask written
void writePhantom(const Phantom& phantom, const PhantomParams& params, const std::string& ctPath,
                  const std::string& truthPath, const std::string& maskPath);

} // namespace flyover
