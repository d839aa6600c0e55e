// Small helpers shared by the scan readers: see io_util.h.

#include "volume/io/io_util.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <sstream>

namespace fs = std::filesystem;

namespace flyover::imageio {

std::string trim(const std::string& s)
{
    const auto a = s.find_first_not_of(" \t\r\n");
    if (a == std::string::npos) return "";
    const auto b = s.find_last_not_of(" \t\r\n");
    return s.substr(a, b - a + 1);
}

std::string sizeText(const std::array<int64_t, 3>& s)
{
    return std::to_string(s[0]) + " x " + std::to_string(s[1]) + " x " + std::to_string(s[2]);
}

std::string bytesText(uint64_t b)
{
    std::ostringstream os;
    os.precision(3);
    if (b >= (1ull << 30)) os << double(b) / double(1ull << 30) << " GiB";
    else if (b >= (1ull << 20)) os << double(b) / double(1ull << 20) << " MiB";
    else os << b << " bytes";
    return os.str();
}

std::string lowerCase(std::string s)
{
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return s;
}

bool endsWith(const std::string& s, const std::string& suffix)
{
    return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

uint64_t fileBytes(const std::string& path)
{
    std::error_code ec;
    const auto n = fs::file_size(path, ec);
    return ec ? 0 : static_cast<uint64_t>(n);
}

std::string fileName(const std::string& path) { return fs::path(path).filename().string(); }

std::string formatFromName(const std::string& path)
{
    const std::string n = lowerCase(fs::path(path).filename().string());
    for (const char* e : {".nii", ".nii.gz", ".hdr", ".img", ".img.gz"})
        if (endsWith(n, e)) return "NIfTI";
    if (endsWith(n, ".nrrd") || endsWith(n, ".nhdr")) return "NRRD";
    if (endsWith(n, ".mha") || endsWith(n, ".mhd")) return "MetaImage";
    if (endsWith(n, ".dcm") || endsWith(n, ".dicom") || endsWith(n, ".ima")) return "DICOM";
    return "";
}

} // namespace flyover::imageio
