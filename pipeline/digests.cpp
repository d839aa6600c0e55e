#include "pipeline/digests.h"

#include "volume/error.h"

#include <xxhash.h>

#include <cstdio>
#include <fstream>
#include <memory>
#include <vector>

namespace flyover {

namespace {

std::string hex128(XXH128_hash_t h)
{
    char buf[33];
    std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(h.high64),
                  static_cast<unsigned long long>(h.low64));
    return buf;
}

} // namespace

std::string fileDigest(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open for reading");
    std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), XXH3_freeState);
    XXH3_128bits_reset(state.get());
    std::vector<char> buf(1 << 20);
    while (in) {
        in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
        XXH3_128bits_update(state.get(), buf.data(), static_cast<std::size_t>(in.gcount()));
    }
    return hex128(XXH3_128bits_digest(state.get()));
}

std::string stringDigest(const std::string& text)
{
    return hex128(XXH3_128bits(text.data(), text.size()));
}

} // namespace flyover
