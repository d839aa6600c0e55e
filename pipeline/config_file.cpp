#include "pipeline/config_file.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"

#include <toml.hpp>

#include <filesystem>
#include <sstream>

namespace flyover {

namespace {

nlohmann::json tomlToJson(const toml::value& v)
{
    switch (v.type()) {
    case toml::value_t::boolean: return v.as_boolean();
    case toml::value_t::integer: return static_cast<int64_t>(v.as_integer());
    case toml::value_t::floating: return v.as_floating();
    case toml::value_t::string: return std::string(v.as_string());
    case toml::value_t::array: {
        nlohmann::json a = nlohmann::json::array();
        for (const auto& e : v.as_array()) a.push_back(tomlToJson(e));
        return a;
    }
    case toml::value_t::table: {
        nlohmann::json o = nlohmann::json::object();
        for (const auto& [k, e] : v.as_table()) o[k] = tomlToJson(e);
        return o;
    }
    default: throw InputError("unsupported TOML value type (dates and times are not parameters)");
    }
}

} // namespace

nlohmann::json readConfigFile(const std::string& path)
{
    if (!std::filesystem::exists(path)) throw InputError(path + ": no such file");
    if (std::filesystem::path(path).extension() != ".toml") return readJson(path);
    try {
        return tomlToJson(toml::parse(path));
    } catch (const std::exception& e) {
        // toml11 messages span several lines: keep the first one, it names the problem.
        std::istringstream in(e.what());
        std::string first;
        std::getline(in, first);
        throw InputError(path + ": not valid TOML: " + first);
    }
}

} // namespace flyover
