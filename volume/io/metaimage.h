/// @file metaimage.h
/// @brief A check of a MetaImage header's text before MetaIO parses it (MetaIO overruns its
///        buffers on malformed lines and on ASCII data, found by fuzzing). Internal to volume/.
#pragma once

#include <string>

namespace flyover::imageio {

/// MetaIO (ITK 5.2) copies field names and values into fixed-size buffers, some of them
/// globals outside any sanitizer's view: a malformed line can corrupt the reading process
/// without crashing the header probe's child (found by fuzzing: a line with no '=' followed by
/// a long one; the parent later died in fflush). So the header text is checked here first,
/// without MetaIO: every line up to and including ElementDataFile is blank or
/// "Name = value" (or "Name: value") with a name of letters, digits and '_' (at most 64) and
/// printable text, at most 1024 characters per line, within the first 64 kB; and the voxel
/// data is binary (BinaryData absent or true).
/// @throw InputError naming the file and the line.
void checkMetaImageHeaderText(const std::string& path);

} // namespace flyover::imageio
