// gzip inflation and temporary folders: see gunzip.h.

#include "volume/io/gunzip.h"

#include "volume/error.h"
#include "volume/io/gzip_stream.h"
#include "volume/io/io_util.h"

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace fs = std::filesystem;

namespace flyover::imageio {

TempDir::TempDir()
{
    std::string pattern = (fs::temp_directory_path() / "flyover-ingest-XXXXXX").string();
    if (!::mkdtemp(pattern.data()))
        throw InputError("cannot create a temporary folder in " + fs::temp_directory_path().string() +
                         ": " + std::strerror(errno) + " (set TMPDIR)");
    mPath = pattern;
}

TempDir::~TempDir()
{
    std::error_code ec;
    fs::remove_all(mPath, ec);
}

void gunzipFile(const fs::path& from, const fs::path& to, uint64_t needBytes, const std::string& name)
{
    GzipStream in(from.string());
    if (!in.error().empty()) throw InputError(name + ": " + in.error());
    std::FILE* out = std::fopen(to.c_str(), "wb");
    if (!out)
        throw InputError(name + ": cannot create the temporary file " + to.string() + ": " + std::strerror(errno) +
                         " (set TMPDIR)");
    std::vector<char> buf(4 << 20);
    std::string problem;
    for (;;) {
        const std::size_t n = in.read(buf.data(), buf.size());
        if (n > 0 && std::fwrite(buf.data(), 1, n, out) != n) {
            problem = "cannot decompress into " + fs::path(to).parent_path().string() + ": " + std::strerror(errno) +
                      " (it needs " + bytesText(needBytes) + "; set TMPDIR to a folder with room)";
            break;
        }
        if (n < buf.size()) break;
    }
    if (problem.empty()) problem = in.error();
    if (std::fclose(out) != 0 && problem.empty())
        problem = "cannot write the temporary file " + to.string() + ": " + std::strerror(errno);
    if (!problem.empty()) throw InputError(name + ": " + problem);
    if (in.position() < needBytes)
        throw InputError(name + ": header/data size mismatch: the header needs " + std::to_string(needBytes) +
                         " bytes, the decompressed file holds " + std::to_string(in.position()) + " (truncated?)");
}

} // namespace flyover::imageio
