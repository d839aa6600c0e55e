#include "pipeline/run_log.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <cstdio>
#include <sys/resource.h>
#include <unistd.h>

namespace flyover {

RunLog::Mode RunLog::defaultMode(int fd) { return ::isatty(fd) ? Mode::Bars : Mode::Plain; }

RunLog::RunLog(Mode mode, std::ostream& out) : mMode(mode), mOut(out) {}

RunLog::~RunLog()
{
    std::lock_guard<std::mutex> lock(mMutex);
    clearBarsLocked();
}

namespace {

std::string seconds(double s)
{
    char buf[32];
    if (s < 60) std::snprintf(buf, sizeof buf, "%.2f s", s);
    else std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
    return buf;
}

void jsonLine(std::ostream& out, nlohmann::json j)
{
    j["time"] = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
    // The process' CPU time (user + system) so far: where the seconds go when the machine is
    // shared and wall times are inflated (bench/first_pair.sh --profile).
    rusage u{};
    if (::getrusage(RUSAGE_SELF, &u) == 0)
        j["cpu_seconds"] = double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
                           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
    out << j.dump() << std::endl;
}

} // namespace

void RunLog::clearBarsLocked()
{
    if (mMode != Mode::Bars) return;
    for (int i = 0; i < mDrawnLines; ++i) mOut << "\x1b[1A\x1b[2K";
    mDrawnLines = 0;
    mOut.flush();
}

void RunLog::redrawLocked(bool force)
{
    if (mMode != Mode::Bars) return;
    const auto now = std::chrono::steady_clock::now();
    if (!force && now - mLastDraw < std::chrono::milliseconds(100)) return;
    mLastDraw = now;
    clearBarsLocked();
    for (const auto& [stage, r] : mRunning) {
        const int width = 30;
        const int filled = static_cast<int>(std::lround(std::clamp(r.fraction, 0.0, 1.0) * width));
        const double elapsed = std::chrono::duration<double>(now - r.start).count();
        std::string eta = "ETA --";
        if (r.fraction > 0.02) eta = "ETA " + seconds(elapsed / r.fraction * (1 - r.fraction));
        char pct[16];
        std::snprintf(pct, sizeof pct, "%3d%%", static_cast<int>(r.fraction * 100));
        mOut << "flyover: " << stage << std::string(std::max<std::size_t>(0, 11 - std::min<std::size_t>(11, stage.size())), ' ')
             << "[" << std::string(filled, '#') << std::string(width - filled, '.') << "] " << pct << "  "
             << seconds(elapsed) << "  " << eta << "  " << r.what << "\n";
        ++mDrawnLines;
    }
    mOut.flush();
}

void RunLog::stageStarted(const std::string& stage)
{
    std::lock_guard<std::mutex> lock(mMutex);
    switch (mMode) {
    case Mode::Quiet: return;
    case Mode::Plain: mOut << "flyover: " << stage << ": running" << std::endl; return;
    case Mode::Json: jsonLine(mOut, {{"event", "stage_started"}, {"stage", stage}}); return;
    case Mode::Bars:
        mRunning[stage] = Running{std::chrono::steady_clock::now(), 0.0, "starting"};
        redrawLocked(true);
        return;
    }
}

void RunLog::stageProgress(const std::string& stage, double fraction, const std::string& what)
{
    std::lock_guard<std::mutex> lock(mMutex);
    if (mMode == Mode::Bars) {
        auto it = mRunning.find(stage);
        if (it == mRunning.end()) return;
        it->second.fraction = fraction;
        it->second.what = what;
        redrawLocked(false);
    } else if (mMode == Mode::Json) {
        jsonLine(mOut, {{"event", "progress"}, {"stage", stage}, {"fraction", fraction}, {"what", what}});
    }
}

void RunLog::stageFinished(const std::string& stage, bool computed, double secs, const std::string& note)
{
    std::lock_guard<std::mutex> lock(mMutex);
    const std::string verb = computed ? "computed in " + seconds(secs) : "reused from the cache";
    switch (mMode) {
    case Mode::Quiet: return;
    case Mode::Plain:
        mOut << "flyover: " << stage << ": " << verb << (note.empty() ? "" : " (" + note + ")") << std::endl;
        return;
    case Mode::Json:
        jsonLine(mOut, {{"event", "stage_finished"}, {"stage", stage}, {"computed", computed},
                        {"wall_seconds", secs}, {"note", note}});
        return;
    case Mode::Bars:
        mRunning.erase(stage);
        clearBarsLocked();
        mOut << "flyover: " << stage << ": " << verb << (note.empty() ? "" : " (" + note + ")") << "\n";
        redrawLocked(true);
        return;
    }
}

void RunLog::message(const std::string& text)
{
    std::lock_guard<std::mutex> lock(mMutex);
    switch (mMode) {
    case Mode::Quiet: return;
    case Mode::Json: jsonLine(mOut, {{"event", "message"}, {"text", text}}); return;
    case Mode::Plain: mOut << "flyover: " << text << std::endl; return;
    case Mode::Bars:
        clearBarsLocked();
        mOut << "flyover: " << text << "\n";
        redrawLocked(true);
        return;
    }
}

void RunLog::firstPair(const std::string& path)
{
    std::lock_guard<std::mutex> lock(mMutex);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - mStart).count();
    // The study (the pair is STUDY/frames/pair_0000.png) can be read now: `flyover view` serves a
    // study that a run is still computing (view/live_study.h).
    const std::string study = std::filesystem::path(path).parent_path().parent_path().string();
    const std::string line = "first fly-over pair: " + path + " (" + seconds(secs) + " after start)\n" +
                             "flyover: read the study now: flyover view --study " + study;
    switch (mMode) {
    case Mode::Quiet: return;
    case Mode::Json: jsonLine(mOut, {{"event", "first_pair"}, {"path", path}, {"seconds_since_start", secs}}); return;
    case Mode::Plain: mOut << "flyover: " << line << std::endl; return;
    case Mode::Bars:
        clearBarsLocked();
        mOut << "flyover: " << line << "\n";
        redrawLocked(true);
        return;
    }
}

} // namespace flyover
