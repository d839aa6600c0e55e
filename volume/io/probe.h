/// @file probe.h
/// @brief Crash-isolated header probes: every header is parsed in a forked child first, so a
///        reader that aborts or crashes on a malformed file (GDCM's assertions, MetaIO's
///        buffer overflows; found by fuzzing) gives an error instead of taking flyover down.
///        Also: choosing the ITK reader for a file. Internal to volume/.
#pragma once

#include <itkImageIOBase.h>

#include <cstdint>
#include <functional>
#include <string>

namespace flyover::imageio {

/// What a forked child did.
struct ChildOutcome {
    bool killed = false;  ///< by a signal: abort() in an assertion, a segfault
    int signal = 0;
    int exitCode = 0;
    std::string output;   ///< what it wrote to its pipe
};

/// Writes all of `text` to `fd` (a child's report pipe); gives up silently on an error.
void writeAll(int fd, const std::string& text);

/// Address space a probing child may add to what it inherits: a malformed length field makes
/// GDCM allocate (and zero) hundreds of megabytes; with the cap the allocation fails quickly
/// instead. Not under AddressSanitizer, which reserves terabytes of shadow memory.
void capChildMemory(uint64_t extraBytes);

/// Runs `body(fd)` in a forked child that reports through the pipe `fd`. Debian builds GDCM
/// with assertions, and some malformed DICOM headers abort() inside it (found by fuzzing:
/// gdcm::ReadExplicitDataElement, "Should not happen"); header parsing therefore runs in a
/// child first, so that such a file is reported instead of taking flyover down. Parsing is
/// deterministic: what the child survived, the parent survives too. The child runs no TBB
/// and writes nothing to the console (FLYOVER_PROBE_STDERR=1 keeps its stderr, for debugging).
ChildOutcome runInChild(uint64_t memoryCapBytes, const std::function<void(int)>& body);

/// "Aborted, signal 6".
std::string signalText(int sig);

/// The reader for a file: chosen by extension for NIfTI, NRRD and MetaImage (so that other
/// readers never parse those files), else by asking every registered reader (DICOM files
/// often have no extension).
itk::ImageIOBase::Pointer createIo(const std::string& path);

/// Every header is parsed in a child first, and its verdict stands: the parent only parses
/// what the child parsed without trouble. Besides GDCM's assertions, fuzzing found a buffer
/// overflow in ITK's MetaIO (a long field name; strcpy in MET_InitReadField, stopped by
/// glibc's fortify checks with abort()). Returns "" when the child read the header, "NOIO"
/// when no reader accepted the file, else the problem in words.
std::string probeHeaderInChild(const std::string& path);

/// Reads the header of `path` with `io`.
/// @throw InputError naming `name` when ITK cannot read it.
void readInformation(itk::ImageIOBase& io, const std::string& path, const std::string& name);

} // namespace flyover::imageio
