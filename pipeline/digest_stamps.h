/// @file digest_stamps.h
/// @brief Cheap re-verification of content digests, so that an unchanged re-run stays within
///        0.3 s instead of hashing ~400 MB again (the scan, ct.vdb, lumen.vdb, surface.ply, frames).
///
/// A stamp is a file's identity as the kernel keeps it — device, inode, size, modification
/// and status-change times in ns — with the content digest the run computed for it. A file
/// whose identity equals its stamp has not been written since (any write, in place or by
/// replacement, moves the status-change time, which no user call can set back), so its
/// digest is taken from the stamp; any other file is hashed. Stamps are taken at the end of
/// a run (after the run's renames and hard links, which move the status-change time too),
/// for the files whose digests this run computed from their content; they live in
/// DIR/.flyover/stamps.json (written atomically; a damaged or missing file means: hash all).
/// What this gives up: a write to a study's file made *during* the run that hashed it, after
/// the hash and before the stamp, is not seen by later runs (the study is locked meanwhile);
/// and a change of the disk's bytes below the file system (bit rot).
#pragma once

#include <map>
#include <mutex>
#include <string>

namespace flyover {

class DigestStamps {
public:
    /// Loads `stampsFile` if it exists and is readable.
    explicit DigestStamps(std::string stampsFile);

    /// Digest of a file, or of a folder (names and digests of its files: artifactDigest's),
    /// each file's from its stamp when its identity is unchanged, else hashed (and to be
    /// stamped by save()). Thread-safe.
    std::string digest(const std::string& path);

    /// Marks `path` (a file) as holding `digest`, computed by this run from its content: it
    /// is stamped by save(). Thread-safe.
    void hashed(const std::string& path, const std::string& digest);

    /// Stamps the files hashed in this run as they are now and writes the stamps file (only
    /// when something changed). Stamps of files that no longer exist are dropped.
    void save();

private:
    struct Stamp {
        unsigned long long dev = 0, ino = 0, size = 0;
        long long mtimeNs = 0, ctimeNs = 0;
        std::string digest;
        bool operator==(const Stamp& o) const
        {
            return dev == o.dev && ino == o.ino && size == o.size && mtimeNs == o.mtimeNs && ctimeNs == o.ctimeNs;
        }
    };
    static bool identity(const std::string& path, Stamp& out);
    std::string fileDigest(const std::string& path);

    std::string mFile;
    std::mutex mMutex;
    std::map<std::string, Stamp> mStamps;           ///< absolute path -> stamp
    std::map<std::string, std::string> mHashed;     ///< absolute path -> digest computed this run
    bool mLoadedAny = false;
};

} // namespace flyover
