#include "pipeline/atomic_write.h"

#include "pipeline/crash_point.h"
#include "pipeline/deferred_writes.h"
#include "volume/error.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <new>
#include <system_error>
#include <unistd.h>

namespace fs = std::filesystem;

namespace flyover {

void fsyncFile(const std::string& path)
{
    if (FILE* f = std::fopen(path.c_str(), "rb")) {
        ::fsync(fileno(f));
        std::fclose(f);
    }
}

void writeAtomically(const std::string& path, const std::function<void(const std::string&)>& write)
{
    const fs::path target(path);
    const fs::path tmp = target.parent_path() /
                         (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string());
    try {
        errno = 0;  // what a failing writer leaves here says why (see the catch below)
        write(tmp.string());
        if (DeferredWrites* deferred = DeferredWrites::active()) {  // write-behind: the fsync and the rename come with finish()
            deferred->add(tmp.string(), path);
            return;
        }
        // Flush the data to disk before the rename makes it visible: a crash must never leave
        // a renamed but empty file.
        fsyncFile(tmp.string());
        crashPoint("atomic-write:before-rename");
        fs::rename(tmp, target);
    } catch (const TransientError&) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw;
    } catch (const std::exception& e) {
        // Writers report "cannot write" without the cause: errno still holds it (a full disk
        // is not a bad input, and a workflow engine should retry it).
        const int error = errno;
        const auto* sys = dynamic_cast<const std::system_error*>(&e);
        const int code = sys ? sys->code().value() : error;
        std::error_code ec;
        fs::remove(tmp, ec);
        if (isTransientErrno(code) || dynamic_cast<const std::bad_alloc*>(&e))
            throw TransientError(path + ": cannot write: " + (dynamic_cast<const std::bad_alloc*>(&e)
                                                                  ? std::string("out of memory")
                                                                  : std::strerror(code)));
        throw;
    }
}

bool isTransientErrno(int error)
{
    switch (error) {
    case ENOSPC: case EDQUOT: case EIO: case ENOMEM: case ESTALE: case ETIMEDOUT:
        return true;
    default:
        return false;
    }
}

void writeFileBytes(const std::string& file, const void* data, std::size_t n)
{
    std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(file.c_str(), "wb"), std::fclose);
    if (!f) throw InputError(file + ": cannot open for writing: " + std::strerror(errno));
    if (std::fwrite(data, 1, n, f.get()) != n || std::fflush(f.get()) != 0)
        throw InputError(file + ": cannot write: " + std::strerror(errno));
}

} // namespace flyover
