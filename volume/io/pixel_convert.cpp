// Native voxel types -> float: see pixel_convert.h.

#include "volume/io/pixel_convert.h"

#include "volume/error.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace flyover::imageio {

std::size_t componentBytes(IOComponentEnum t)
{
    switch (t) {
    case IOComponentEnum::UCHAR: case IOComponentEnum::CHAR: return 1;
    case IOComponentEnum::USHORT: case IOComponentEnum::SHORT: return 2;
    case IOComponentEnum::UINT: case IOComponentEnum::INT: case IOComponentEnum::FLOAT: return 4;
    case IOComponentEnum::ULONG: case IOComponentEnum::LONG: return sizeof(long);
    case IOComponentEnum::ULONGLONG: case IOComponentEnum::LONGLONG: case IOComponentEnum::DOUBLE: return 8;
    default: return 0;  // unknown or long double: not supported
    }
}

namespace {

template <typename T>
void convertSpan(const void* src, std::size_t n, float* dst)
{
    const T* s = static_cast<const T*>(src);
    for (std::size_t i = 0; i < n; ++i) dst[i] = static_cast<float>(s[i]);
}

} // namespace

/// Native voxels -> float. Returns the index of the first non-finite value, or n.
std::size_t toFloat(const void* src, IOComponentEnum t, std::size_t n, float* dst)
{
    switch (t) {
    case IOComponentEnum::UCHAR: convertSpan<uint8_t>(src, n, dst); return n;
    case IOComponentEnum::CHAR: convertSpan<int8_t>(src, n, dst); return n;
    case IOComponentEnum::USHORT: convertSpan<uint16_t>(src, n, dst); return n;
    case IOComponentEnum::SHORT: convertSpan<int16_t>(src, n, dst); return n;
    case IOComponentEnum::UINT: convertSpan<uint32_t>(src, n, dst); return n;
    case IOComponentEnum::INT: convertSpan<int32_t>(src, n, dst); return n;
    case IOComponentEnum::ULONG: convertSpan<unsigned long>(src, n, dst); return n;
    case IOComponentEnum::LONG: convertSpan<long>(src, n, dst); return n;
    case IOComponentEnum::ULONGLONG: convertSpan<unsigned long long>(src, n, dst); return n;
    case IOComponentEnum::LONGLONG: convertSpan<long long>(src, n, dst); return n;
    case IOComponentEnum::FLOAT: convertSpan<float>(src, n, dst); break;
    case IOComponentEnum::DOUBLE: convertSpan<double>(src, n, dst); break;
    default: throw std::logic_error("toFloat: unsupported component type");
    }
    // Floating-point input: NaN, Inf, and doubles beyond float range (now Inf) are refused.
    return static_cast<std::size_t>(std::find_if(dst, dst + n, [](float v) { return !std::isfinite(v); }) - dst);
}

[[noreturn]] void throwNonFinite(const std::string& name, const std::array<int64_t, 3>& size, int64_t k0,
                                 std::size_t n, float value)
{
    const int64_t sliceSize = size[0] * size[1];
    const int64_t i = static_cast<int64_t>(n) % size[0];
    const int64_t j = (static_cast<int64_t>(n) % sliceSize) / size[0];
    const int64_t k = k0 + static_cast<int64_t>(n) / sliceSize;
    std::ostringstream os;
    os << name << ": voxel (" << i << "," << j << "," << k << ") is " << value
       << "; NaN and Inf voxels are not allowed";
    throw InputError(os.str());
}

IOComponentEnum niftiComponentType(int datatype, int& bytes)
{
    switch (datatype) {
    case 2: bytes = 1; return IOComponentEnum::UCHAR;       // DT_UINT8
    case 256: bytes = 1; return IOComponentEnum::CHAR;      // DT_INT8
    case 4: bytes = 2; return IOComponentEnum::SHORT;       // DT_INT16
    case 512: bytes = 2; return IOComponentEnum::USHORT;    // DT_UINT16
    case 8: bytes = 4; return IOComponentEnum::INT;         // DT_INT32
    case 768: bytes = 4; return IOComponentEnum::UINT;      // DT_UINT32
    case 16: bytes = 4; return IOComponentEnum::FLOAT;      // DT_FLOAT32
    case 1024: bytes = 8; return IOComponentEnum::LONGLONG; // DT_INT64
    case 1280: bytes = 8; return IOComponentEnum::ULONGLONG;// DT_UINT64
    case 64: bytes = 8; return IOComponentEnum::DOUBLE;     // DT_FLOAT64
    default: bytes = 0; return IOComponentEnum::UNKNOWNCOMPONENTTYPE;
    }
}

} // namespace flyover::imageio
