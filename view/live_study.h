/// @file live_study.h
/// @brief The study `flyover view` serves, kept in step with its folder, so that the viewer
///        can show a study that is still being computed. A watcher polls the files the viewer reads
///        (centerline.json, surface.ply, ct.vdb, coverage/coverage.json, manifest.json); when
///        they have changed and then held still for one more poll, it loads a new ViewStudy in
///        the background (taking the surface's scene and the CT grid over from the study served
///        when their files are the same) and swaps it in under a new revision. A run's first
///        study is served with a fast-built scene and without its CT grid; the next revision,
///        at the next look, has both. While a
///        `flyover run` holds the study's lock and has not yet written the surface or the
///        centerline, nothing is served: requests get StudyNotReady (HTTP 503) and status()
///        says what is awaited. A study that lacks them with no run computing it is refused at
///        once, as before.
#pragma once

#include "view/view_study.h"

#include <nlohmann/json.hpp>

#include <array>
#include <condition_variable>
#include <cstdint>
#include <istream>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace flyover {

/// What tells a file's versions apart without reading it: absent, or its size, modification
/// time and inode (a run replaces its files by renaming, which changes the inode).
struct FileStamp {
    bool exists = false;
    std::uintmax_t size = 0;
    std::int64_t mtimeNs = 0;
    std::uint64_t inode = 0;
    bool operator==(const FileStamp& o) const
    {
        return exists == o.exists && size == o.size && mtimeNs == o.mtimeNs && inode == o.inode;
    }
    bool operator!=(const FileStamp& o) const { return !(*this == o); }
};

FileStamp fileStamp(const std::string& path);

/// Whether a process holds the flock of `studyDir`/.flyover/lock (a `flyover run` writing the
/// study), read from /proc/locks: the lock is never taken, so a run starting at that moment is
/// never refused because of the viewer.
bool studyLockHeld(const std::string& studyDir);

/// studyLockHeld()'s reading of /proc/locks: whether a granted FLOCK lock is held on the file
/// (device, inode); where the device differs (an overlay file system names the lower one), a
/// holder whose pid is `filePid` (the pid a run writes into its lock file) counts too.
bool flockHeldIn(std::istream& procLocks, unsigned devMajor, unsigned devMinor, unsigned long long inode,
                 long filePid);

/// A request the study cannot answer yet (HTTP 503): its surface or centerline is still being
/// computed, or is loading.
struct StudyNotReady : std::runtime_error {
    using std::runtime_error::runtime_error;
};

class LiveStudy {
public:
    struct Options {
        double pollSeconds = 0.1;  ///< how often the files and the lock are looked at
    };

    /// Reads the study's small files at once when the surface and centerline are there (its
    /// errors are thrown here, as ViewStudy's); else, with a run holding the study's lock,
    /// waits for them. @throw InputError as ViewStudy's constructor when they are missing and
    /// no run holds the lock.
    LiveStudy(const std::string& studyDir, const std::string& ctPath, Options options);
    LiveStudy(const std::string& studyDir, const std::string& ctPath) : LiveStudy(studyDir, ctPath, Options()) {}
    ~LiveStudy();
    LiveStudy(const LiveStudy&) = delete;
    LiveStudy& operator=(const LiveStudy&) = delete;

    /// Starts loading the first study in the background (when there is one) and the watcher.
    void start();
    /// Stops the watcher (waits for a reload under way).
    void stop();

    /// The study served now (its methods wait for its load, as a plain ViewStudy's do).
    /// @throw StudyNotReady while none is served, naming what is awaited.
    /// `revision`: where given, set to the revision of the study returned.
    std::shared_ptr<const ViewStudy> current(int* revision = nullptr) const;
    /// The first study's load ended: true when a study was there at construction (then its
    /// load error, if any, is thrown). For `flyover view`, which stops on a broken study.
    /// Returns false at once when the study was being computed at construction.
    bool waitFirstLoad() const;

    /// `GET /api/status`: revision (0: none served yet, +1 at each study swapped in), ready,
    /// computing (a run holds the lock), loading, waiting_for (needed files missing), stages
    /// (manifest.json's, in order), complete, error ("" or the last load's failure).
    nlohmann::json status() const;
    /// Why no study is served ("" when one is): being computed (waiting for which files),
    /// loading, lacking files with no run computing it, or the load's failure.
    std::string notReadyReason() const;
    int revision() const;
    const std::string& studyDir() const { return mDir; }

private:
    /// The watched files' stamps: centerline.json, surface.ply, ct.vdb, coverage.json, manifest.json.
    using Stamps = std::array<FileStamp, 5>;
    Stamps readStamps() const;
    void watch();
    /// Loads the study as `stamps` found it, reusing what `previous` loaded from unchanged files.
    void reload(const Stamps& stamps);
    std::vector<std::string> missing(const Stamps& stamps) const;
    std::string notReadyReasonLocked() const;

    std::string mDir, mCtPath;
    Options mOptions;
    std::shared_ptr<ViewStudy> mFirst;  ///< the study there at construction (loading in the background)

    mutable std::mutex mMutex;  // guards the fields below
    std::shared_ptr<ViewStudy> mServed;
    Stamps mServedStamps{}, mTriedStamps{}, mSeenStamps{};
    int mRevision = 0;
    bool mComputing = false, mLoading = false;
    bool mProvisional = false;  ///< the study served has a fast-built scene: rebuilt at the next look
    std::string mError;
    nlohmann::json mStages = nlohmann::json::array();
    bool mComplete = false;
    FileStamp mManifestStamp;

    bool mStop = false;
    std::condition_variable mStopCv;
    std::thread mWatcher;
};

} // namespace flyover
