#include "view/image_codec.h"

#include <png.h>
#include <turbojpeg.h>

#include <memory>
#include <stdexcept>

namespace flyover {

namespace {

void appendToString(png_structp png, png_bytep data, png_size_t length)
{
    auto* out = static_cast<std::string*>(png_get_io_ptr(png));
    out->append(reinterpret_cast<const char*>(data), length);
}

void noFlush(png_structp) {}

std::string encodePngRows(int width, int height, int colorType, int channels, const uint8_t* pixels)
{
    if (width <= 0 || height <= 0) throw std::runtime_error("encodePng: empty image");
    std::string out;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!png || !info) {
        png_destroy_write_struct(&png, &info);
        throw std::runtime_error("encodePng: libpng initialisation failed");
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        throw std::runtime_error("encodePng: libpng failed to encode");
    }
    png_set_write_fn(png, &out, appendToString, noFlush);
    png_set_compression_level(png, 3);
    png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), 8, colorType, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < height; ++y)
        png_write_row(png, const_cast<png_bytep>(pixels + std::size_t(y) * std::size_t(width) * std::size_t(channels)));
    png_write_end(png, nullptr);
    png_destroy_write_struct(&png, &info);
    return out;
}

} // namespace

std::string encodePng(const RgbImage& image)
{
    if (image.rgb.size() != std::size_t(image.width) * std::size_t(image.height) * 3)
        throw std::runtime_error("encodePng: the buffer does not match the image size");
    return encodePngRows(image.width, image.height, PNG_COLOR_TYPE_RGB, 3, image.rgb.data());
}

std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray)
{
    if (gray.size() != std::size_t(width) * std::size_t(height))
        throw std::runtime_error("encodeGrayPng: the buffer does not match the image size");
    return encodePngRows(width, height, PNG_COLOR_TYPE_GRAY, 1, gray.data());
}

std::string encodeJpeg(const RgbImage& image, int quality)
{
    if (image.width <= 0 || image.height <= 0 ||
        image.rgb.size() != std::size_t(image.width) * std::size_t(image.height) * 3)
        throw std::runtime_error("encodeJpeg: the buffer does not match the image size");
    std::unique_ptr<void, int (*)(tjhandle)> tj(tjInitCompress(), tjDestroy);
    if (!tj) throw std::runtime_error("encodeJpeg: tjInitCompress failed");
    unsigned char* buf = nullptr;
    unsigned long size = 0;
    if (tjCompress2(tj.get(), image.rgb.data(), image.width, 0, image.height, TJPF_RGB, &buf, &size, TJSAMP_420,
                    quality, TJFLAG_FASTDCT) != 0) {
        const std::string msg = tjGetErrorStr2(tj.get());
        tjFree(buf);
        throw std::runtime_error("encodeJpeg: " + msg);
    }
    std::string out(reinterpret_cast<const char*>(buf), size);
    tjFree(buf);
    return out;
}

} // namespace flyover
