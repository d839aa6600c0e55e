/// @file data_size.h
/// @brief Where a header's voxels live on disk and whether the file holds them all: ITK's
///        readers zero-fill a truncated .nii and only print a message for a short MetaImage,
///        so sizes are checked here before reading. Internal to volume/.
#pragma once

#include "volume/image.h"

#include <itkImageIOBase.h>

#include <cstdint>
#include <filesystem>
#include <string>

namespace flyover::imageio {

/// A string entry of the reader's metadata dictionary, trimmed ("" when absent).
std::string metaString(const itk::ImageIOBase& io, const std::string& key);

/// Where a header's voxels live on disk (as far as the header tells).
struct DataFile {
    std::filesystem::path path;  ///< empty: unknown (several files, or a reader we cannot ask)
    uint64_t offset = 0;         ///< bytes before the voxels
    uint64_t bytes = 0;          ///< voxel bytes as stored
    bool compressed = false;
};

/// The data file of a NIfTI or MetaImage header ITK has read (else an empty DataFile).
/// @throw InputError for MetaImage file lists and patterns (not supported).
DataFile dataFileOf(itk::ImageIOBase& io, const std::string& path);

/// @throw InputError naming `path` when an uncompressed data file is missing or short.
void checkDataSize(const DataFile& f, const std::string& path, const ImageGeometry& g, const std::string& typeName);

} // namespace flyover::imageio
