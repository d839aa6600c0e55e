/// @file stage_run.h
/// @brief What the engine knows of a run: its options, its parameters, the study folder, and
///        the hand-ons through which a stage body starts early work. An application derives
///        its own run context from it (the results its stages hand on in memory) and its stage
///        table's bodies take that.
#pragma once

#include "pipeline/param_set.h"
#include "pipeline/study.h"

#include <chrono>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <utility>

namespace flyover {

class StageRun {
public:
    StageRun(const StudyOptions& o, const ParamSet& p)
        : options(o), params(p), dir(o.studyDir), start(std::chrono::steady_clock::now()) {}
    virtual ~StageRun() = default;
    StageRun(const StageRun&) = delete;
    StageRun& operator=(const StageRun&) = delete;

    std::string path(const std::string& name) const { return (dir / name).string(); }

    /// Mid-body hand-ons: a stage body puts into the graph a result it holds in the run's
    /// state before its artifacts are written, and the early nodes that read it start then
    /// (a render step may also hand on a point the write-behind's commits wait for).
    /// This is the one thing an edge from the stage's node cannot say: that node ends only
    /// with the body. runStudy hands on, after the body, whatever a body did not (reused,
    /// not wanted, failed), so each hand-on happens exactly once.
    /// @param what a name of the stage table's hand-ons ("segment:uncut-lumen", say).
    void handOn(const std::string& what) const
    {
        if (mHandOn) mHandOn(what);
    }
    /// How many early nodes of this run read `what` (the body keeps what it hands on only for them).
    int earlyReaders(const std::string& what) const
    {
        const auto it = mEarlyReaders.find(what);
        return it == mEarlyReaders.end() ? 0 : it->second;
    }
    /// Set by runStudy when it builds the graph.
    void setHandOns(std::function<void(const std::string&)> handOn, std::map<std::string, int> earlyReaders)
    {
        mHandOn = std::move(handOn);
        mEarlyReaders = std::move(earlyReaders);
    }

    const StudyOptions& options;
    const ParamSet& params;
    std::filesystem::path dir;
    std::chrono::steady_clock::time_point start;  ///< when the run started

private:
    std::function<void(const std::string&)> mHandOn;
    std::map<std::string, int> mEarlyReaders;
};

} // namespace flyover
