/// @file process_memory.h
/// @brief The memory figures the benchmarks print about their own (child) process.
#pragma once

#include <sys/resource.h>

#include <fstream>
#include <string>

namespace flyover::bench {

/// Peak resident set size of this process so far (MB): what /usr/bin/time -v reports as
/// "Maximum resident set size".
inline double peakRssMb()
{
    rusage usage{};
    ::getrusage(RUSAGE_SELF, &usage);
    return double(usage.ru_maxrss) / 1024.0;  // Linux: kilobytes
}

/// Resident set size of this process now (MB), from /proc/self/status.
inline double currentRssMb()
{
    std::ifstream status("/proc/self/status");
    std::string line;
    while (std::getline(status, line))
        if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
    return 0;
}

} // namespace flyover::bench
