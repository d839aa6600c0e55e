/// @file atomic_write.h
/// @brief Atomic writes of a study's files: a temporary name in the same folder, then a rename
///        (deferred to the stage's commit under write-behind, pipeline/deferred_writes.h).
#pragma once

#include <cstddef>
#include <functional>
#include <stdexcept>
#include <string>

namespace flyover {

/// The machine, not the input, failed while storing a result (disk full, quota, I/O error,
/// out of memory, a stale network file handle): worth retrying, possibly elsewhere.
/// `flyover` exits with EX_TEMPFAIL (75) for it (see pipeline/stage_command.h).
struct TransientError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// True for errno values that say the machine, not the input, failed (ENOSPC, EDQUOT, EIO,
/// ENOMEM, ESTALE, ETIMEDOUT).
bool isTransientErrno(int error);

/// Writes a file atomically: `write` receives a temporary path in the same folder (with the
/// same extension, for writers that pick the format by extension), which is then renamed
/// onto `path`. On any exception the temporary file is removed and the exception rethrown, as a
/// TransientError naming `path` when errno says the disk or the machine failed (full, I/O).
void writeAtomically(const std::string& path, const std::function<void(const std::string& tmpPath)>& write);

/// Writes `n` bytes to `file` (created or truncated) in one call. @throw InputError naming it.
void writeFileBytes(const std::string& file, const void* data, std::size_t n);

/// fsyncs a file's data (a no-op when it cannot be opened).
void fsyncFile(const std::string& path);

} // namespace flyover
