// Crash-isolated header probes and reader choice: see probe.h.

#include "volume/io/probe.h"

#include "volume/io/io_util.h"
#include "volume/io/itk_console.h"

#include <itkImageIOFactory.h>
#include <itkMetaImageIO.h>
#include <itkNiftiImageIO.h>
#include <itkNrrdImageIO.h>

#include "volume/error.h"

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <mutex>

#include <fcntl.h>
#include <sys/resource.h>
#include "volume/fd_write.h"

#include <sys/wait.h>
#include <unistd.h>

namespace flyover::imageio {

void writeAll(int fd, const std::string& text)
{
    (void)writeFully(fd, text.data(), text.size());  // a broken pipe: the parent sees a short answer
}

void capChildMemory(uint64_t extraBytes)
{
#if defined(__SANITIZE_ADDRESS__)
    const bool underAsan = true;
#elif defined(__has_feature)
    const bool underAsan = __has_feature(address_sanitizer);
#else
    const bool underAsan = false;
#endif
    if (underAsan) return;
    long pages = 0;
    if (std::FILE* f = std::fopen("/proc/self/statm", "r")) {
        if (std::fscanf(f, "%ld", &pages) != 1) pages = 0;
        std::fclose(f);
    }
    if (pages <= 0) return;
    const rlim_t limit = static_cast<rlim_t>(pages) * static_cast<rlim_t>(::sysconf(_SC_PAGESIZE)) + extraBytes;
    const rlimit as{limit, limit};
    ::setrlimit(RLIMIT_AS, &as);
}

ChildOutcome runInChild(uint64_t memoryCapBytes, const std::function<void(int)>& body)
{
    int fds[2];
    if (::pipe(fds) != 0) throw InputError(std::string("cannot create a pipe: ") + std::strerror(errno));
    std::cout.flush();
    std::cerr.flush();
    std::fflush(nullptr);
    // One fork at a time: ITK's thread pool stops and restarts its threads in fork handlers,
    // which deadlocks when two threads fork at once.
    static std::mutex forkMutex;
    pid_t pid;
    {
        std::lock_guard<std::mutex> lock(forkMutex);
        pid = ::fork();
    }
    if (pid < 0) {
        ::close(fds[0]);
        ::close(fds[1]);
        throw InputError(std::string("cannot fork to check a header: ") + std::strerror(errno));
    }
    if (pid == 0) {
        ::close(fds[0]);
        for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL}) std::signal(sig, SIG_DFL);
        const rlimit noCore{0, 0};  // an abort in the child is expected: no core dump
        ::setrlimit(RLIMIT_CORE, &noCore);
        capChildMemory(memoryCapBytes);
        if (!std::getenv("FLYOVER_PROBE_STDERR")) {
            const int devnull = ::open("/dev/null", O_WRONLY);
            if (devnull >= 0) {
                ::dup2(devnull, STDOUT_FILENO);
                ::dup2(devnull, STDERR_FILENO);
            }
        }
        int code = 0;
        try {
            body(fds[1]);
        } catch (...) {
            code = 3;
        }
        ::_exit(code);
    }
    ::close(fds[1]);
    ChildOutcome out;
    char buf[1 << 14];
    for (;;) {
        const ssize_t n = ::read(fds[0], buf, sizeof buf);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) break;
        out.output.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fds[0]);
    int status = 0;
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    out.killed = WIFSIGNALED(status);
    out.signal = out.killed ? WTERMSIG(status) : 0;
    out.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : 0;
    return out;
}

std::string signalText(int sig)
{
    const char* name = ::strsignal(sig);
    return std::string(name ? name : "signal") + ", signal " + std::to_string(sig);
}

itk::ImageIOBase::Pointer createIo(const std::string& path)
{
    CapturedOutput capture;
    const std::string format = formatFromName(path);
    itk::ImageIOBase::Pointer io;
    if (format == "NIfTI") io = itk::NiftiImageIO::New();
    else if (format == "NRRD") io = itk::NrrdImageIO::New();
    else if (format == "MetaImage") io = itk::MetaImageIO::New();
    else return itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::CommonEnums::IOFileMode::ReadMode);
    return io->CanReadFile(path.c_str()) ? io : nullptr;
}

std::string probeHeaderInChild(const std::string& path)
{
    const std::string format = formatFromName(path);
    const std::string reader = format == "NIfTI"       ? "NIfTI reader (ITK's niftilib)"
                               : format == "NRRD"      ? "NRRD reader (ITK's NrrdIO)"
                               : format == "MetaImage" ? "MetaImage reader (ITK's MetaIO)"
                                                       : "image reader (ITK; GDCM for DICOM)";
    const ChildOutcome child = runInChild(2 * fileBytes(path) + (uint64_t(512) << 20), [&](int fd) {
        std::string verdict = "OK";
        itk::ImageIOBase::Pointer io;
        try {
            io = createIo(path);
            if (!io) {
                verdict = "NOIO";
            } else {
                CapturedOutput capture;
                io->SetFileName(path);
                io->ReadImageInformation();
            }
        } catch (const itk::ExceptionObject& e) {
            verdict = "ERR cannot read the " + (io ? formatOfIo(*io) : format) + " header: " + itkReason(e);
        } catch (const std::exception& e) {
            verdict = "ERR cannot read the " + (io ? formatOfIo(*io) : format) + " header: " + e.what();
        }
        writeAll(fd, verdict);
    });
    if (child.killed)
        return "malformed file: the " + reader + " crashed on its header (" + signalText(child.signal) + ")";
    if (child.exitCode != 0)
        throw std::runtime_error(path + ": header probe exited with code " + std::to_string(child.exitCode));
    if (child.output == "NOIO") return "NOIO";
    if (child.output.rfind("ERR ", 0) == 0) return child.output.substr(4);
    return "";
}

void readInformation(itk::ImageIOBase& io, const std::string& path, const std::string& name)
{
    try {
        CapturedOutput capture;
        io.SetFileName(path);
        io.ReadImageInformation();
    } catch (const itk::ExceptionObject& e) {
        throw InputError(name + ": cannot read the " + formatOfIo(io) + " header: " + itkReason(e));
    }
}

} // namespace flyover::imageio
