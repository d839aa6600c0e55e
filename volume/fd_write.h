// Writing a whole buffer to a file descriptor (a file or a pipe): write() until every byte is
// out, again after a signal interrupted it (EINTR).
#pragma once

#include <cerrno>
#include <cstddef>
#include <unistd.h>

namespace flyover {

/// Writes `size` bytes of `data` to `fd`. @return 0, or the errno of the write that failed
/// (EIO for a write that wrote nothing).
inline int writeFully(int fd, const void* data, std::size_t size)
{
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        const ssize_t n = ::write(fd, p, size);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return n < 0 ? errno : EIO;
        p += n;
        size -= static_cast<std::size_t>(n);
    }
    return 0;
}

} // namespace flyover
