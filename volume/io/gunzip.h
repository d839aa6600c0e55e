/// @file gunzip.h
/// @brief Inflating gzipped voxel data (.nii.gz, .img.gz) to a file (gzip_stream.h, which
///        reports truncated and corrupt streams; ITK's readers zero-fill them), and a private
///        temporary folder for the copy. Internal to volume/.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

namespace flyover::imageio {

/// A private temporary folder, removed with everything in it.
class TempDir {
public:
    /// @throw InputError when no folder can be created in $TMPDIR.
    TempDir();
    ~TempDir();
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    const std::filesystem::path& path() const { return mPath; }

private:
    std::filesystem::path mPath;
};

/// Decompresses `from` into `to`; refuses truncated or corrupt streams and output
/// shorter than `needBytes`. Messages name `name`.
/// @throw InputError.
void gunzipFile(const std::filesystem::path& from, const std::filesystem::path& to, uint64_t needBytes,
                const std::string& name);

} // namespace flyover::imageio
