/// @file io_util.h
/// @brief Small helpers shared by the scan readers (volume/io/): text for messages, file
///        names and sizes, the format a file name promises. Internal to volume/.
#pragma once

#include <array>
#include <cstdint>
#include <string>

namespace flyover::imageio {

/// `s` without leading and trailing blanks (space, tab, CR, LF).
std::string trim(const std::string& s);
/// "512 x 512 x 448".
std::string sizeText(const std::array<int64_t, 3>& s);
/// "235 MiB", "1.2 GiB", "812 bytes".
std::string bytesText(uint64_t b);
std::string lowerCase(std::string s);
bool endsWith(const std::string& s, const std::string& suffix);
/// Size of a file in bytes; 0 when it cannot be read.
uint64_t fileBytes(const std::string& path);
/// The last component of a path.
std::string fileName(const std::string& path);
/// The format a file name promises ("NIfTI", "NRRD", "MetaImage", "DICOM" or ""), for
/// choosing a reader and for messages when no reader accepts the file.
std::string formatFromName(const std::string& path);

} // namespace flyover::imageio
