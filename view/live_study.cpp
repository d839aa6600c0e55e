#include "view/live_study.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"

#include <sys/stat.h>
#include <sys/sysmacros.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

/// The watched files, in the order of LiveStudy::Stamps.
enum Watched { CENTERLINE, SURFACE, CT, COVERAGE, MANIFEST };

std::string joinNames(const std::vector<std::string>& names)
{
    std::string out;
    for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
    return out;
}

} // namespace

FileStamp fileStamp(const std::string& path)
{
    struct stat st {};
    FileStamp s;
    if (::stat(path.c_str(), &st) != 0 || !(S_ISREG(st.st_mode) || S_ISDIR(st.st_mode))) return s;
    s.exists = true;
    s.size = std::uintmax_t(st.st_size);
    s.mtimeNs = std::int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
    s.inode = std::uint64_t(st.st_ino);
    return s;
}

bool flockHeldIn(std::istream& procLocks, unsigned devMajor, unsigned devMinor, unsigned long long inode,
                 long filePid)
{
    // Lines such as "3: FLOCK  ADVISORY  WRITE 4242 fd:01:1234567 0 EOF"; a process waiting for
    // a lock has "->" after the number (it does not hold it).
    std::string line;
    while (std::getline(procLocks, line)) {
        std::istringstream words(line);
        std::string w;
        bool flock = false, waiting = false;
        long previous = -1;
        while (words >> w) {
            if (w == "->") waiting = true;
            else if (w == "FLOCK") flock = true;
            else if (std::count(w.begin(), w.end(), ':') == 2 && flock && !waiting) {
                const long pid = previous;  // the field before the device names the holder
                unsigned maj = 0, min = 0;
                unsigned long long ino = 0;
                if (std::sscanf(w.c_str(), "%x:%x:%llu", &maj, &min, &ino) == 3 && ino == inode &&
                    ((maj == devMajor && min == devMinor) || (pid > 0 && pid == filePid)))
                    return true;
                break;
            } else {
                char* end = nullptr;
                const long v = std::strtol(w.c_str(), &end, 10);
                previous = (end && *end == '\0') ? v : -1;
            }
        }
    }
    return false;
}

bool studyLockHeld(const std::string& studyDir)
{
    struct stat st {};
    const std::string lock = (fs::path(studyDir) / ".flyover" / "lock").string();
    if (::stat(lock.c_str(), &st) != 0) return false;
    // The pid a run writes into the lock file (StudyLock): on an overlay file system /proc/locks
    // names the lower file system's device, not the one stat() gives, so the holder's pid
    // stands in for the device there.
    long filePid = -1;
    {
        std::ifstream in(lock);
        if (!(in >> filePid)) filePid = -1;
    }
    std::ifstream locks("/proc/locks");
    return flockHeldIn(locks, major(st.st_dev), minor(st.st_dev), static_cast<unsigned long long>(st.st_ino),
                       filePid);
}

LiveStudy::LiveStudy(const std::string& studyDir, const std::string& ctPath, Options options)
    : mDir(studyDir), mCtPath(ctPath), mOptions(options)
{
    const Stamps stamps = readStamps();
    mSeenStamps = stamps;
    if (missing(stamps).empty() || !fs::is_directory(studyDir) || !studyLockHeld(studyDir)) {
        // A study to show now (or to refuse now, with ViewStudy's one line naming what lacks).
        mFirst = std::make_shared<ViewStudy>(studyDir, ctPath);
        mServed = mFirst;
        mServedStamps = mTriedStamps = stamps;
        mRevision = 1;
    } else {
        mComputing = true;
    }
}

LiveStudy::~LiveStudy() { stop(); }

void LiveStudy::start()
{
    if (mFirst) mFirst->startLoading();
    if (!mWatcher.joinable()) mWatcher = std::thread([this] { watch(); });
}

void LiveStudy::stop()
{
    {
        std::lock_guard<std::mutex> lock(mMutex);
        mStop = true;
    }
    mStopCv.notify_all();
    if (mWatcher.joinable()) mWatcher.join();
}

LiveStudy::Stamps LiveStudy::readStamps() const
{
    const fs::path d(mDir);
    return Stamps{fileStamp((d / "centerline.json").string()), fileStamp((d / "surface.ply").string()),
                  fileStamp(mCtPath.empty() ? (d / "ct.vdb").string() : mCtPath),
                  fileStamp((d / "coverage" / "coverage.json").string()), fileStamp((d / "manifest.json").string())};
}

std::vector<std::string> LiveStudy::missing(const Stamps& stamps) const
{
    std::vector<std::string> out;
    if (!stamps[SURFACE].exists) out.push_back("surface.ply");
    if (!stamps[CENTERLINE].exists) out.push_back("centerline.json");
    return out;
}

void LiveStudy::watch()
{
    const auto poll = std::chrono::duration<double>(mOptions.pollSeconds);
    for (;;) {
        {
            std::unique_lock<std::mutex> lock(mMutex);
            if (mStopCv.wait_for(lock, poll, [this] { return mStop; })) return;
        }
        const Stamps now = readStamps();
        const bool computing = studyLockHeld(mDir);
        json stages = nullptr;
        bool complete = false;
        if (now[MANIFEST] != mManifestStamp) {
            try {
                const json m = readJson((fs::path(mDir) / "manifest.json").string());
                stages = json::array();
                if (m.contains("stages") && m["stages"].is_array())
                    for (const auto& e : m["stages"])
                        if (e.is_object() && e.contains("stage") && e["stage"].is_string()) stages.push_back(e["stage"]);
                complete = m.value("complete", false);
            } catch (const std::exception&) {
                stages = nullptr;  // being replaced, or broken: read it again at the next poll
            }
        }
        bool stable = false, due = false;
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mComputing = computing;
            if (!stages.is_null()) {
                mStages = stages;
                mComplete = complete;
                mManifestStamp = now[MANIFEST];
            }
            stable = now == mSeenStamps;  // held still for one poll: a run's burst of renames is over
            mSeenStamps = now;
            due = stable && (now != mTriedStamps || mProvisional);
            if (due && !missing(now).empty()) {
                mTriedStamps = now;  // nothing to load: the study served (if any) stays
                due = false;
            }
        }
        if (due) reload(now);
    }
}

void LiveStudy::reload(const Stamps& stamps)
{
    std::shared_ptr<ViewStudy> previous;
    Stamps previousStamps{};
    bool computing = false, previousProvisional = false;
    {
        std::lock_guard<std::mutex> lock(mMutex);
        previous = mServed;
        previousStamps = mServedStamps;
        previousProvisional = mProvisional;
        computing = mComputing;
        mLoading = true;
    }
    Stamps served = stamps;
    bool provisional = false;
    try {
        auto next = std::make_shared<ViewStudy>(mDir, mCtPath);
        if (!previous && computing) {
            // The first study of a run in progress, as soon as can be: its scene built fast
            // (Morton BVH: 0.3 s instead of 0.6-0.9 s for 2.5 M triangles) and without the CT
            // grid (224 MB on the full phantom); the next revision, at the next look, rebuilds
            // the scene at Embree's default quality and reads the CT.
            next->buildSceneFast();
            provisional = true;
            if (mCtPath.empty() && stamps[CT].exists) {
                next->leaveOutCt();
                served[CT] = FileStamp{};
            }
        }
        if (previous) {
            try {
                next->reuse(*previous, stamps[SURFACE] == previousStamps[SURFACE] && !previousProvisional,
                            stamps[CT] == previousStamps[CT]);
            } catch (const std::exception&) {
                // the study served failed to load: read everything
            }
        }
        next->load();
        std::lock_guard<std::mutex> lock(mMutex);
        mServed = std::move(next);
        mServedStamps = mTriedStamps = served;
        mProvisional = provisional;
        ++mRevision;
        mError.clear();
        mLoading = false;
    } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(mMutex);
        mTriedStamps = stamps;  // tried again once the files change
        mProvisional = false;   // (not at every look: the fast-built scene stays served)
        mError = e.what();
        mLoading = false;
    }
}

std::string LiveStudy::notReadyReasonLocked() const
{
    if (mServed) return "";
    if (mLoading) return "the study is loading";
    const std::vector<std::string> lacks = missing(mSeenStamps);
    if (!lacks.empty())
        return mComputing ? "the study is being computed: waiting for " + joinNames(lacks)
                          : "the study lacks " + joinNames(lacks) + " and no flyover run is computing it";
    return "the study could not be loaded: " + mError;
}

std::string LiveStudy::notReadyReason() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    return notReadyReasonLocked();
}

std::shared_ptr<const ViewStudy> LiveStudy::current(int* revision) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    if (revision) *revision = mRevision;
    if (!mServed) throw StudyNotReady(notReadyReasonLocked());
    return mServed;
}

bool LiveStudy::waitFirstLoad() const
{
    if (!mFirst) return false;
    mFirst->waitLoaded();
    return true;
}

int LiveStudy::revision() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    return mRevision;
}

json LiveStudy::status() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    const std::vector<std::string> lacks = missing(mSeenStamps);
    // A run that ended without the files is an error too (the page says so).
    const std::string error = !mError.empty() || mServed || mComputing || mLoading || lacks.empty()
                                  ? mError
                                  : notReadyReasonLocked();
    return json{{"revision", mRevision},   {"ready", bool(mServed)}, {"computing", mComputing},
                {"loading", mLoading},     {"waiting_for", lacks},   {"stages", mStages},
                {"complete", mComplete},   {"error", error}};
}

} // namespace flyover
