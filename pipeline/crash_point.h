/// @file crash_point.h
/// @brief The crash-test hook of the atomic writes and the write-behind.
#pragma once

namespace flyover {

/// Crash-test hook: when the environment variable FLYOVER_CRASH_AT equals `point`, the
/// process kills itself with SIGKILL right there (as `kill -9` would). Used by the tests to
/// crash at exact moments (mid-write, between a cache object and its record); a no-op
/// otherwise.
void crashPoint(const char* point);

} // namespace flyover
