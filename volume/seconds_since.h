/// @file seconds_since.h
/// @brief Wall time since a steady-clock instant, in seconds: the one helper for stage and
///        step timings in reports and benchmarks.
#pragma once

#include <chrono>

namespace flyover {

inline double secondsSince(std::chrono::steady_clock::time_point start)
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

} // namespace flyover
