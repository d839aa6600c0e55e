/// @file deferred_writes.h
/// @brief Write-behind of a stage's artifacts, so that the next stages need not wait for the
///        disk. While a DeferredWrites::Scope is
///        open on a thread, writeAtomically() (artifact_io.h) writes each file to its temporary
///        as usual but leaves the rename and the fsync to DeferredWrites::rename() and sync().
///        The pipeline hashes the temporaries at once (so that the next stages' keys stay
///        content digests and they can start) and runs rename(), sync() and the cache record
///        beside the next stages. A run killed before rename() leaves only temporaries, which
///        the next run removes; nothing
///        is recorded before its files are renamed and on disk.
#pragma once

#include <nlohmann/json.hpp>

#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace flyover {

class DeferredWrites {
public:
    DeferredWrites() = default;
    /// Removes the temporaries of writes never finished (a failing stage).
    ~DeferredWrites();
    DeferredWrites(const DeferredWrites&) = delete;
    DeferredWrites& operator=(const DeferredWrites&) = delete;

    /// Defers the writes of this thread to `writes` while it lives, or writes at once when
    /// `writes` is null. Nests: a TBB thread may run another stage's body while it waits inside
    /// one, so every stage body runs in a scope of its own. Only writes made on the scope's own
    /// thread are deferred (not those of a parallel loop's workers).
    class Scope {
    public:
        explicit Scope(DeferredWrites* writes);
        ~Scope();
        Scope(const Scope&) = delete;
        Scope& operator=(const Scope&) = delete;

    private:
        DeferredWrites* mPrevious;
    };

    /// The deferred writes of this thread, or null when no Scope is open.
    static DeferredWrites* active();

    /// Records a complete temporary file that is to replace `path`.
    void add(const std::string& tmpPath, const std::string& path);
    /// The temporary holding the deferred write of `path`, or "" when there is none.
    std::string pendingFile(const std::string& path) const;
    /// Renames each temporary onto its name, in the order written: the files reach their
    /// names (and an open `flyover view`) at once, without waiting for the disk.
    /// @throw std::filesystem::filesystem_error when a rename fails.
    void rename();
    /// fsyncs each file rename() renamed. The pipeline writes the stage's cache record only
    /// after it: a file renamed but not yet on disk when the machine loses power has no
    /// record, so no later run trusts it.
    void sync();

    /// Leaves part of the stage's report to be made behind: `complete` runs in
    /// completeReport(), beside the next stages and before the cache record is written (so a
    /// record always holds the whole report), and fills in what the body left out. It may only
    /// read what the next stages read (they run meanwhile).
    void addReportPart(std::function<void(nlohmann::json&)> complete);
    /// Runs the parts added, in order, on `report`.
    void completeReport(nlohmann::json& report);

private:
    std::vector<std::pair<std::string, std::string>> mFiles;  ///< (temporary, final name)
    std::vector<std::string> mRenamed;                        ///< renamed, not yet fsynced
    std::vector<std::function<void(nlohmann::json&)>> mReportParts;
};

/// The file holding `path`'s newest content: the temporary of a write deferred on this thread,
/// else `path` itself.
std::string writtenFile(const std::string& path);

} // namespace flyover
