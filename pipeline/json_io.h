/// @file json_io.h
/// @brief JSON artifacts: atomic writes and strict reads, and centerline.json's schema.
#pragma once

#include "volume/centerline_types.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>

#include <string>

namespace flyover {

void writeJson(const std::string& path, const nlohmann::json& j);
/// @throw InputError naming the file when it is missing or not valid JSON.
nlohmann::json readJson(const std::string& path);

inline nlohmann::json vec3Json(const Vec3d& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

/// centerline.json: documented schema "flyover.centerline/1", LPS mm, columnar arrays.
nlohmann::json centerlineToJson(const Centerline& centerline);
Centerline centerlineFromJson(const nlohmann::json& j, const std::string& source);

} // namespace flyover
