/// @file pixel_convert.h
/// @brief Voxels in a file's native type (int8..uint64, float, double) -> float HU, with
///        NaN/Inf refused in one line naming the voxel. Internal to volume/.
#pragma once

#include <itkIOCommon.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

namespace flyover::imageio {

using itk::IOComponentEnum;

/// Bytes of one voxel of type `t`; 0 when the type is not supported.
std::size_t componentBytes(IOComponentEnum t);

/// The voxel type of a NIfTI-1 or NIfTI-2 datatype code (the two share them) and its size in
/// `bytes`; UNKNOWNCOMPONENTTYPE and 0 bytes for complex, RGB and float128.
IOComponentEnum niftiComponentType(int datatype, int& bytes);

/// Native voxels -> float. Returns the index of the first non-finite value, or n.
std::size_t toFloat(const void* src, IOComponentEnum t, std::size_t n, float* dst);

/// @throw InputError naming `name` and voxel `n` of the slab that starts at slice k0.
[[noreturn]] void throwNonFinite(const std::string& name, const std::array<int64_t, 3>& size, int64_t k0,
                                 std::size_t n, float value);

} // namespace flyover::imageio
