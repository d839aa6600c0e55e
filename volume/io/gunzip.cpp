// gzip inflation and temporary folders: see gunzip.h.

#include "volume/io/gunzip.h"

#include "volume/error.h"
#include "volume/io/io_util.h"

#include <zlib.h>

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
    gzFile in = ::gzopen(from.c_str(), "rb");
    if (!in) throw InputError(name + ": cannot open " + from.string() + ": " + std::strerror(errno));
    ::gzbuffer(in, 1 << 20);
    std::FILE* out = std::fopen(to.c_str(), "wb");
    if (!out) {
        ::gzclose(in);
        throw InputError(name + ": cannot create the temporary file " + to.string() + ": " +
                         std::strerror(errno) + " (set TMPDIR)");
    }
    std::vector<char> buf(4 << 20);
    uint64_t total = 0;
    std::string problem;
    for (;;) {
        const int n = ::gzread(in, buf.data(), static_cast<unsigned>(buf.size()));
        if (n < 0) break;
        if (n == 0) break;
        if (std::fwrite(buf.data(), 1, static_cast<std::size_t>(n), out) != static_cast<std::size_t>(n)) {
            problem = "cannot decompress into " + fs::path(to).parent_path().string() + ": " + std::strerror(errno) +
                      " (it needs " + bytesText(needBytes) + "; set TMPDIR to a folder with room)";
            break;
        }
        total += static_cast<uint64_t>(n);
    }
    int err = Z_OK;
    const char* zmsg = ::gzerror(in, &err);
    if (problem.empty() && err != Z_OK && err != Z_STREAM_END) {
        std::string why = zmsg ? zmsg : "zlib error";
        const std::string prefix = from.string() + ": ";  // zlib names the file itself
        if (why.rfind(prefix, 0) == 0) why = why.substr(prefix.size());
        problem = "gzip data is truncated or corrupt after " + std::to_string(total) + " decompressed bytes (" + why + ")";
    }
    ::gzclose(in);
    if (std::fclose(out) != 0 && problem.empty())
        problem = "cannot write the temporary file " + to.string() + ": " + std::strerror(errno);
    if (!problem.empty()) throw InputError(name + ": " + problem);
    if (total < needBytes)
        throw InputError(name + ": header/data size mismatch: the header needs " + std::to_string(needBytes) +
                         " bytes, the decompressed file holds " + std::to_string(total) + " (truncated?)");
}

} // namespace flyover::imageio
