/// @file voids.cpp
/// @brief Internal voids of a solid part (see voids.h).
#include "volume/voids.h"

#include "volume/error.h"

#include <stdexcept>

namespace flyover {

PartAnalysis analysePart(const openvdb::FloatGrid& /*ct*/, const VoidParams& /*params*/,
                         const std::string& /*sourceName*/, Progress* /*progress*/)
{
    throw std::logic_error("analysePart: not implemented yet");
}

} // namespace flyover
