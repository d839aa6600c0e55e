// Where the project's shared data lies (shared/data beside the checkout: the real scans the
// tests use when this machine has them). Looked for at run time, so a checkout anywhere (the
// main one, a git worktree in a sub-folder, a build folder elsewhere) finds it.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <string>

namespace flyover::test {

/// $FLYOVER_SHARED_DATA when set; else A/shared/data for the nearest folder A that holds one,
/// from the source tree's parent upwards (/work/main and a worktree /work/wt/x both find
/// /work/shared/data). Empty when there is none.
inline std::string sharedDataDir()
{
    namespace fs = std::filesystem;
    if (const char* env = std::getenv("FLYOVER_SHARED_DATA"); env && *env) return env;
    std::error_code ec;
    fs::path dir = fs::weakly_canonical(fs::path(FLYOVER_SOURCE_DIR), ec);
    if (ec) dir = fs::path(FLYOVER_SOURCE_DIR);
    for (fs::path a = dir.parent_path(); !a.empty(); a = a.parent_path()) {
        if (fs::is_directory(a / "shared" / "data", ec)) return (a / "shared" / "data").string();
        if (a == a.parent_path()) break;
    }
    return {};
}

/// A sentence for a skipped test: where the shared data was looked for.
inline std::string sharedDataLookedFor(const std::string& relative)
{
    return "no shared data " + relative + " (looked for shared/data/" + relative + " in every parent of " +
           std::string(FLYOVER_SOURCE_DIR) + "; FLYOVER_SHARED_DATA overrides)";
}

} // namespace flyover::test
