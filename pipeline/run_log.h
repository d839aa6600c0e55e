/// @file run_log.h
/// @brief What a run tells its user: one progress bar per running stage with an ETA on a
///        terminal, plain log lines otherwise (CI, pipes), JSON lines for scripts, or nothing.
#pragma once

#include "volume/progress.h"

#include <chrono>
#include <map>
#include <mutex>
#include <ostream>
#include <string>

namespace flyover {

class RunLog {
public:
    enum class Mode { Quiet, Plain, Bars, Json };

    /// Bars when `out` is a terminal and mode was not forced, else Plain.
    static Mode defaultMode(int fd);

    RunLog(Mode mode, std::ostream& out);
    ~RunLog();

    void stageStarted(const std::string& stage);
    void stageProgress(const std::string& stage, double fraction, const std::string& what);
    /// @param computed  false when reused from the cache
    void stageFinished(const std::string& stage, bool computed, double seconds, const std::string& note);
    void message(const std::string& text);
    /// The first fly-over pair is on disk at `path`: a log line, or the JSON event
    /// {"event": "first_pair", "path": ..., "seconds_since_start": ...} (since this log was made,
    /// i.e. since the command started).
    void firstPair(const std::string& path);

    Mode mode() const { return mMode; }

private:
    struct Running {
        std::chrono::steady_clock::time_point start;
        double fraction = 0;
        std::string what;
    };
    void redrawLocked(bool force);
    void clearBarsLocked();

    Mode mMode;
    std::ostream& mOut;
    std::mutex mMutex;
    std::map<std::string, Running> mRunning;
    int mDrawnLines = 0;
    std::chrono::steady_clock::time_point mLastDraw;
    std::chrono::steady_clock::time_point mStart = std::chrono::steady_clock::now();
};

/// Adapts RunLog to the Progress interface stage code polls.
class StageProgress : public Progress {
public:
    StageProgress(RunLog* log, std::string stage) : mLog(log), mStage(std::move(stage)) {}
    void update(double fraction, const std::string& what) override
    {
        if (mLog) mLog->stageProgress(mStage, fraction, what);
    }

private:
    RunLog* mLog;
    std::string mStage;
};

} // namespace flyover
