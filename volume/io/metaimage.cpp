// MetaImage header text check: see metaimage.h.

#include "volume/io/metaimage.h"

#include "volume/error.h"
#include "volume/io/io_util.h"

#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>

namespace flyover::imageio {

void checkMetaImageHeaderText(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open: " + std::strerror(errno));
    std::string text(64 << 10, '\0');
    in.read(text.data(), std::streamsize(text.size()));
    text.resize(static_cast<std::size_t>(in.gcount()));
    std::size_t pos = 0;
    for (int line = 1; pos < text.size(); ++line) {
        std::size_t end = text.find('\n', pos);
        const bool complete = end != std::string::npos;
        if (!complete) end = text.size();
        std::string l = text.substr(pos, end - pos);
        pos = end + 1;
        if (!l.empty() && l.back() == '\r') l.pop_back();
        auto bad = [&](const std::string& why) {
            throw InputError(path + ": MetaImage header line " + std::to_string(line) + " " + why);
        };
        if (l.size() > 1024) bad("is longer than 1024 characters");
        for (unsigned char c : l)
            if (c != '\t' && (c < 32 || c > 126)) bad("holds a non-printable character");
        const std::string t = trim(l);
        if (t.empty()) continue;
        std::size_t n = 0;
        while (n < t.size() && (std::isalnum(static_cast<unsigned char>(t[n])) || t[n] == '_')) ++n;
        if (n == 0 || !std::isalpha(static_cast<unsigned char>(t[0]))) bad("does not start with a field name");
        if (n > 64) bad("has a field name longer than 64 characters");
        const std::size_t sep = t.find_first_not_of(" \t", n);
        if (sep == std::string::npos || (t[sep] != '=' && t[sep] != ':')) bad("is not 'Name = value'");
        const std::string name = t.substr(0, n), value = trim(t.substr(sep + 1));
        // ASCII voxel data (BinaryData false): MetaIO's region reader writes past the region's
        // buffer (found by fuzzing: heap corruption). MetaIO takes T, t or 1 for true.
        if (name == "BinaryData" && (value.empty() || std::string("Tt1").find(value[0]) == std::string::npos))
            bad("says BinaryData = " + value.substr(0, 20) + ": ASCII voxel data is not supported");
        if (name == "ElementDataFile") return;
        if (!complete) break;
    }
    throw InputError(path + ": MetaImage header has no ElementDataFile field in its first 64 kB");
}

} // namespace flyover::imageio
