/// @file config_file.h
/// @brief Reads a parameter file, JSON or TOML (by extension: .toml is TOML, anything else
///        JSON), into the JSON form {"stage": {"param": value}} that applyParamsJson takes.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace flyover {

/// @throw InputError naming the file and the parse error (with its line for TOML).
nlohmann::json readConfigFile(const std::string& path);

} // namespace flyover
