/// @file artifact_store.h
/// @brief The study's content-addressed cache: every stage result is kept under
///        DIR/.flyover/ as objects named by their digest plus one record per stage key, so a
///        re-run reuses what did not change and switching a parameter back to an earlier value
///        reuses the earlier result. Least-recently-used records are evicted above a size cap.
///
/// Layout:
///   DIR/.flyover/lock                      advisory lock held by a running `flyover run`
///   DIR/.flyover/objects/<digest>.<ext>    a file artifact (hard-linked into DIR/<name>)
///   DIR/.flyover/objects/<digest>.d/       a folder artifact (frames/)
///   DIR/.flyover/records/<stage>-<key>.json  the stage's parameters, input and output digests
#pragma once

#include <nlohmann/json.hpp>

#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>

namespace flyover {

/// Thrown when the study is locked by another run.
struct StudyBusy : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// Exclusive advisory lock on a study (flock): released when destroyed or when the process dies.
class StudyLock {
public:
    /// @param wait  block until the lock is free instead of refusing
    /// @throw StudyBusy naming the study and the holder's pid when it is locked and !wait
    StudyLock(const std::string& studyDir, bool wait);
    ~StudyLock();
    StudyLock(const StudyLock&) = delete;
    StudyLock& operator=(const StudyLock&) = delete;

private:
    int mFd = -1;
};

/// A stage's cache key: a digest of (stage, version, canonical parameters, input digests).
std::string stageKey(const std::string& stage, int version, const nlohmann::json& params,
                     const std::map<std::string, std::string>& inputDigests);

/// Digest of a file artifact, or of a folder artifact (names and digests of its files).
/// fileDigestOf digests one file (fileDigest, or a cache of it such as DigestStamps').
std::string artifactDigest(const std::string& path,
                           const std::function<std::string(const std::string&)>& fileDigestOf = {});

class DigestStamps;

class ArtifactStore {
public:
    /// @param stamps  when given, verifyRecord() takes the digests of unchanged objects from
    ///                it instead of hashing them (digest_stamps.h)
    explicit ArtifactStore(const std::string& studyDir, DigestStamps* stamps = nullptr);

    /// Removes temporary files left by a killed run (call while holding the study lock).
    void removeStaleTemporaries() const;

    /// The record of a stage key, if one exists.
    std::optional<nlohmann::json> findRecord(const std::string& stage, const std::string& key) const;

    /// Checks that every output object of a record exists and still has its digest.
    /// @return empty when intact, else a short description of the first problem.
    std::string verifyRecord(const nlohmann::json& record) const;

    /// Makes DIR/<name> the stored object of every output of the record (hard links).
    void materialize(const nlohmann::json& record) const;

    /// Stores the freshly written outputs DIR/<name> as objects and writes the record.
    /// `record` must hold "stage", "key" and "outputs" {name: digest}.
    void commit(const nlohmann::json& record) const;

    /// Marks a record as used now (for least-recently-used eviction).
    void touch(const std::string& stage, const std::string& key) const;

    /// Whether a record of `stage` other than `exceptKey` lists `digest` for the output `name`.
    bool anotherRecordHas(const std::string& stage, const std::string& name, const std::string& digest,
                          const std::string& exceptKey) const;

    /// Drops a record (e.g. after its objects were found corrupt).
    void dropRecord(const std::string& stage, const std::string& key) const;

    /// Evicts least-recently-used records (never those in `keep`) until the objects take at
    /// most `maxBytes`; deletes objects no longer referenced. @return bytes freed.
    uint64_t evict(uint64_t maxBytes, const std::set<std::string>& keepRecordFiles) const;

    /// Total bytes of stored objects.
    uint64_t objectBytes() const;

    /// Record file name of a stage key (as used in `keep`).
    static std::string recordFileName(const std::string& stage, const std::string& key);

    std::string objectPath(const std::string& name, const std::string& digest) const;

private:
    std::string mDir;
    DigestStamps* mStamps = nullptr;
};

} // namespace flyover
