#pragma once
/// @file param_json.h
/// @brief Strict JSON -> parameter reading shared by the colon's stages (params.cpp) and
///        `flyover inspect` (inspect_params.cpp): each parameter struct lists its fields once in a
///        visit function; this reads one JSON object of a stage into it, refusing unknown keys and
///        values of the wrong type with one line naming `stage.key`.

#include "volume/error.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <string>

namespace flyover::param_json {

inline void readNumber(const nlohmann::json& j, double& out, const std::string& name)
{
    if (!j.is_number()) throw ParameterError(name + ": expected a number, got " + j.dump());
    out = j.get<double>();
    if (!std::isfinite(out)) throw ParameterError(name + ": must be finite");
}
inline void readInteger(const nlohmann::json& j, int& out, const std::string& name)
{
    if (!j.is_number_integer()) throw ParameterError(name + ": expected an integer, got " + j.dump());
    out = j.get<int>();
}
inline void readBool(const nlohmann::json& j, bool& out, const std::string& name)
{
    if (!j.is_boolean()) throw ParameterError(name + ": expected true or false, got " + j.dump());
    out = j.get<bool>();
}

/// Reads the object `j` into `p`. `forEachField(p, f)` calls f(key, value&, help) for each field
/// (the struct's visit function); `read(json, value&, "stage.key")` converts one value.
/// `owner` names the stage in the unknown-key message ("segment", "inspect voids").
template <typename P, typename ForEachField, typename Read>
void readObject(P& p, const nlohmann::json& j, const std::string& stage, const std::string& owner,
                ForEachField&& forEachField, Read&& read)
{
    if (!j.is_object()) throw ParameterError(stage + ": expected an object of parameters");
    for (auto it = j.begin(); it != j.end(); ++it) {
        bool found = false;
        forEachField(p, [&](const char* key, auto& value, const char*) {
            if (it.key() == key) {
                read(it.value(), value, stage + "." + key);
                found = true;
            }
        });
        if (!found) {
            std::string known;
            forEachField(p, [&](const char* key, auto&, const char*) {
                known += (known.empty() ? "" : ", ") + std::string(key);
            });
            throw ParameterError("unknown parameter '" + stage + "." + it.key() + "' (" + owner +
                                 " has: " + known + ")");
        }
    }
}

} // namespace flyover::param_json
