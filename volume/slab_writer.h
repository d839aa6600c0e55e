/// @file slab_writer.h
/// @brief Writes a uint16 volume slice by slice (k slowest), so that a generator of any size
///        holds one slab, never the volume: NIfTI-1 (.nii, .nii.gz) and NRRD (.nrrd).
///
/// Formats (chosen by the file name):
/// - `.nii`: NIfTI-1 single file, uint16 (DT_UINT16), little endian, vox_offset 352; the
///   affine is written as qform and sform (NIfTI's RAS: x and y of our LPS negated).
/// - `.nii.gz`: the same, gzip-compressed by zlib as it is written (level 1).
/// - `.nrrd`: NRRD 4, `space: left-posterior-superior`, raw little-endian uint16.
/// Geometry: the direction cosines must be the identity (axis-aligned, LPS), which is all the
/// generators here need. The file is written under a temporary name in the same folder and
/// renamed into place by finish(); a writer destroyed before finish() removes the temporary,
/// so no half-written volume is ever left under the final name.
#pragma once

#include "volume/image.h"

#include <cstdint>
#include <memory>
#include <string>

namespace flyover {

class SlabWriter {
public:
    /// @throw ParameterError for an unknown extension or a non-identity direction;
    ///        InputError when the file cannot be created (naming it)
    SlabWriter(const std::string& path, const ImageGeometry& geometry);
    ~SlabWriter();
    SlabWriter(const SlabWriter&) = delete;
    SlabWriter& operator=(const SlabWriter&) = delete;

    /// Appends the next slice: size[0] * size[1] values, i fastest.
    /// @throw InputError on a write error (disk full), naming the file
    void writeSlice(const uint16_t* voxels);
    /// Checks that every slice was written, closes and renames the file into place.
    void finish();

    /// Peak bytes this writer buffers (one slice).
    std::size_t bufferedBytes() const;

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

} // namespace flyover
