/// @file image_codec.h
/// @brief In-memory image encoding for the viewer's HTTP answers: PNG through libpng (as the
///        rest of the project), JPEG through libturbojpeg.
#pragma once

#include "render/render_view.h"

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// 8-bit RGB PNG (compression level 3, as the frames). @throw std::runtime_error on a libpng failure.
std::string encodePng(const RgbImage& image);
/// 8-bit grayscale PNG of width x height bytes, top row first.
std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray);
/// Baseline JPEG, 4:2:0, quality 1..100. @throw std::runtime_error with turbojpeg's message.
std::string encodeJpeg(const RgbImage& image, int quality = 88);

} // namespace flyover
