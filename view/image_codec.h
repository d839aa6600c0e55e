/// @file image_codec.h
/// @brief In-memory image encoding for the viewer's HTTP answers: PNG by the frames' encoder
///        (pipeline/artifact_io.h: encodePng, encodeGrayPng), JPEG through libturbojpeg.
#pragma once

#include "pipeline/artifact_io.h"
#include "render/render_view.h"

#include <cstdint>
#include <string>
#include <vector>

namespace flyover {

/// Baseline JPEG, 4:2:0, quality 1..100. @throw std::runtime_error with turbojpeg's message.
std::string encodeJpeg(const RgbImage& image, int quality = 88);

} // namespace flyover
