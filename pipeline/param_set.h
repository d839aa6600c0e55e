/// @file param_set.h
/// @brief An application's parameters as the engine sees them: sections of canonical JSON (the
///        cache keys cover them), a version per section, validation, and the parsing of
///        `--config` and `--set`. The engine never sees the application's parameter structs.
#pragma once

#include <nlohmann/json.hpp>

#include <memory>
#include <string>
#include <vector>

namespace flyover {

class ParamSet {
public:
    virtual ~ParamSet() = default;
    /// The section names, in the order the manifest lists them.
    virtual const std::vector<std::string>& sections() const = 0;
    /// One section's parameters as canonical JSON (sorted keys, units in the names).
    virtual nlohmann::json sectionJson(const std::string& section) const = 0;
    /// The version of the stage that owns `section` (bumped when its output's meaning changes).
    virtual int sectionVersion(const std::string& section) const = 0;
    /// @throw ParameterError naming the parameter out of range.
    virtual void validate() const = 0;
    /// A `--config` file's (or a manifest's) sections {"section": {"param": value}}.
    /// @throw ParameterError naming an unknown key or a bad value, and `source`.
    virtual void applyJson(const nlohmann::json& config, const std::string& source) = 0;
    /// One `--set section.param=value`. @throw ParameterError.
    virtual void applyAssignment(const std::string& assignment) = 0;
    virtual std::unique_ptr<ParamSet> clone() const = 0;
};

/// A ParamSet over an application's parameter struct `P`, through its free functions.
template <class P, const std::vector<std::string>& (*Sections)(), nlohmann::json (*ToJson)(const P&, const std::string&),
          int (*Version)(const std::string&), void (*Validate)(const P&),
          void (*ApplyJson)(P&, const nlohmann::json&, const std::string&), void (*Assign)(P&, const std::string&)>
class ParamSetOf final : public ParamSet {
public:
    explicit ParamSetOf(P p = P()) : params(std::move(p)) {}
    const std::vector<std::string>& sections() const override { return Sections(); }
    nlohmann::json sectionJson(const std::string& s) const override { return ToJson(params, s); }
    int sectionVersion(const std::string& s) const override { return Version(s); }
    void validate() const override { Validate(params); }
    void applyJson(const nlohmann::json& c, const std::string& source) override { ApplyJson(params, c, source); }
    void applyAssignment(const std::string& a) override { Assign(params, a); }
    std::unique_ptr<ParamSet> clone() const override { return std::make_unique<ParamSetOf>(params); }
    P params;
};

} // namespace flyover
