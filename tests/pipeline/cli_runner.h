// Running the flyover binary (or another program) from a test: exit code, stdout and stderr.
#pragma once

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace flyover::test {

struct CliResult {
    int exitCode = -1;
    std::string out;  ///< stdout
    std::string err;  ///< stderr
};

/// Runs `PROGRAM ARGS` (ARGS through the shell) and collects what it printed.
inline CliResult runProgram(const std::string& program, const std::string& args)
{
    namespace fs = std::filesystem;
    const fs::path errFile = fs::temp_directory_path() /
                             (fs::path(program).filename().string() + "-cli-" + std::to_string(::getpid()) + ".err");
    const std::string cmd = program + " " + args + " 2>" + errFile.string();
    CliResult r;
    FILE* p = ::popen(cmd.c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf;
    std::size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
    const int status = ::pclose(p);
    r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    std::ifstream in(errFile);
    r.err.assign(std::istreambuf_iterator<char>(in), {});
    fs::remove(errFile);
    return r;
}

#ifdef FLYOVER_BIN
/// Runs `flyover ARGS` (ARGS through the shell) and collects what it printed.
inline CliResult runFlyover(const std::string& args) { return runProgram(FLYOVER_BIN, args); }
#endif

inline int lineCount(const std::string& s)
{
    int n = 0;
    for (char c : s) n += c == '\n';
    return n;
}

} // namespace flyover::test
