/// @file digests.h
/// @brief Content digests of files and strings (xxHash3-128): the cache keys and artifacts' identities.
#pragma once

#include <string>

namespace flyover {

/// xxHash3-128 of a file's content as 32 hex digits. @throw InputError if unreadable.
std::string fileDigest(const std::string& path);
/// xxHash3-128 of a string, 32 hex digits.
std::string stringDigest(const std::string& text);

} // namespace flyover
