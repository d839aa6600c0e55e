/// @file staged_folder.h
/// @brief A folder artifact written under a temporary name and renamed into place.
#pragma once

#include <filesystem>
#include <string>
#include <system_error>
#include <unistd.h>

namespace flyover {

namespace fs = std::filesystem;

/// A folder written under a temporary name that replaces `dir/name` only on commit(); removed
/// if never committed (an exception on the way), so a half-written folder is never trusted.
class StagedFolder {
public:
    StagedFolder(const fs::path& dir, const std::string& name)
        : mTarget(dir / name), mTmp(dir / (".tmp-" + std::to_string(::getpid()) + "-" + name))
    {
        fs::remove_all(mTmp);
        fs::create_directories(mTmp);
    }
    ~StagedFolder()
    {
        std::error_code ec;
        if (!mCommitted) fs::remove_all(mTmp, ec);
    }
    StagedFolder(const StagedFolder&) = delete;
    StagedFolder& operator=(const StagedFolder&) = delete;

    std::string path(const std::string& file) const { return (mTmp / file).string(); }

    void commit()
    {
        const fs::path old = mTarget.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-old-" +
                                                      mTarget.filename().string());
        fs::remove_all(old);
        if (fs::exists(mTarget)) fs::rename(mTarget, old);
        fs::rename(mTmp, mTarget);
        fs::remove_all(old);
        mCommitted = true;
    }

private:
    fs::path mTarget, mTmp;
    bool mCommitted = false;
};

} // namespace flyover
