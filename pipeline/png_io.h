/// @file png_io.h
/// @brief PNG artifacts: the frames' encoder (ISA-L deflate) and the readers (a fast path for
///        plain RGB files, libpng for the rest).
#pragma once

#include "render/render_view.h"

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// PNG file bytes of an 8-bit RGB image: every row filtered with Up, one IDAT deflated by ISA-L
/// (level 1, zlib stream). The frames' writer and the viewer's answers. @throw InputError.
std::string encodePng(const RgbImage& image);
/// 8-bit grayscale PNG of width x height bytes, top row first, encoded as encodePng.
std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray);
void writePng(const std::string& path, const RgbImage& image);
/// Reads an 8-bit RGB or RGBA PNG (alpha dropped). Plain 8-bit RGB files (the frames') are
/// decoded by decodePlainRgbPng, every other file and any file it declines by libpng.
/// @throw InputError.
RgbImage readPng(const std::string& path);
/// The pixels of a plain PNG file's bytes: 8-bit RGB, not interlaced, only IHDR, IDAT, IEND and
/// text, time and pHYs chunks, every critical chunk's CRC right and the zlib stream whole
/// (ISA-L inflate, Adler-32 checked) and exactly one image long. @return false for any other
/// or damaged file (readPng leaves those to libpng); true: the values libpng would return.
bool decodePlainRgbPng(const std::string& bytes, RgbImage& out);

} // namespace flyover
