#include "pipeline/png_io.h"

#include "pipeline/atomic_write.h"
#include "volume/error.h"

#include <isa-l/crc.h>
#include <isa-l/igzip_lib.h>
#include <png.h>

#include <cstring>
#include <fstream>
#include <memory>
#include <vector>

namespace flyover {

namespace {

void appendU32(std::string& out, uint32_t v)
{
    for (int shift = 24; shift >= 0; shift -= 8) out.push_back(static_cast<char>(v >> shift));
}

/// One PNG chunk: length, type, data, and the CRC-32 of type and data.
void appendChunk(std::string& out, const char* type, const void* data, std::size_t n)
{
    appendU32(out, static_cast<uint32_t>(n));
    const std::size_t typeAt = out.size();
    out.append(type, 4);
    if (n) out.append(static_cast<const char*>(data), n);
    // ISA-L's CRC-32 of gzip, the same polynomial and reflection as PNG's (zlib's crc32).
    appendU32(out, crc32_gzip_refl(0, reinterpret_cast<const unsigned char*>(out.data() + typeAt), 4 + n));
}

/// PNG bytes of 8-bit pixels, `channels` 1 (gray) or 3 (RGB) per pixel, top row first.
std::string encodePngPixels(int width, int height, int channels, const uint8_t* pixels)
{
    if (width <= 0 || height <= 0) throw InputError("encodePng: empty image");
    if (static_cast<std::size_t>(width) * std::size_t(channels) + 1 >
        (std::size_t(1) << 30) / static_cast<std::size_t>(height))
        throw InputError("encodePng: " + std::to_string(width) + " x " + std::to_string(height) +
                         " px is too large for one image");
    // Frames are many: favour speed. Every row filtered with Up (the difference to the row
    // above, which the fly-over's smooth shading makes mostly small), deflated by ISA-L at
    // level 1 into one zlib stream: about 4x faster than zlib's run-length deflate at level 3,
    // the files ~15% larger; the pixels are the same.
    const std::size_t rowBytes = static_cast<std::size_t>(width) * std::size_t(channels);
    const std::size_t rows = static_cast<std::size_t>(height);
    thread_local std::vector<unsigned char> filtered, deflated, levelBuffer;
    filtered.resize((rowBytes + 1) * rows);
    for (std::size_t y = 0; y < rows; ++y) {
        unsigned char* out = filtered.data() + y * (rowBytes + 1);
        const unsigned char* row = pixels + y * rowBytes;
        out[0] = 2;  // filter type Up (the first row's "above" is zero)
        if (y == 0) {
            std::memcpy(out + 1, row, rowBytes);
        } else {
            const unsigned char* above = row - rowBytes;
            for (std::size_t i = 0; i < rowBytes; ++i) out[1 + i] = static_cast<unsigned char>(row[i] - above[i]);
        }
    }
    levelBuffer.resize(ISAL_DEF_LVL1_DEFAULT);
    // Stored blocks bound the output: the input plus 5 bytes per 64 KiB, the zlib header and
    // its Adler-32; grown below should ISA-L ever need more.
    deflated.resize(filtered.size() + filtered.size() / 8 + 1024);
    isal_zstream z;
    isal_deflate_init(&z);
    z.level = 1;
    z.level_buf = levelBuffer.data();
    z.level_buf_size = static_cast<uint32_t>(levelBuffer.size());
    z.gzip_flag = IGZIP_ZLIB;
    z.end_of_stream = 1;
    z.flush = NO_FLUSH;
    z.next_in = filtered.data();
    z.avail_in = static_cast<uint32_t>(filtered.size());
    z.next_out = deflated.data();
    z.avail_out = static_cast<uint32_t>(deflated.size());
    while (z.internal_state.state != ZSTATE_END) {
        if (z.avail_out == 0) {
            const std::size_t used = deflated.size();
            deflated.resize(2 * used);
            z.next_out = deflated.data() + used;
            z.avail_out = static_cast<uint32_t>(deflated.size() - used);
        }
        const int rc = isal_deflate(&z);
        if (rc != COMP_OK) throw std::runtime_error("encodePng: ISA-L deflate failed (" + std::to_string(rc) + ")");
    }
    const std::size_t idatBytes = static_cast<std::size_t>(z.total_out);

    std::string png("\x89PNG\r\n\x1a\n", 8);
    png.reserve(idatBytes + 64);
    std::string ihdr;
    appendU32(ihdr, static_cast<uint32_t>(width));
    appendU32(ihdr, static_cast<uint32_t>(height));
    const char colourType = channels == 3 ? 2 : 0;  // RGB or gray
    ihdr += {8, colourType, 0, 0, 0};  // 8 bits, deflate, filter method 0, no interlace
    appendChunk(png, "IHDR", ihdr.data(), ihdr.size());
    appendChunk(png, "IDAT", deflated.data(), idatBytes);
    appendChunk(png, "IEND", nullptr, 0);
    return png;
}

} // namespace

std::string encodePng(const RgbImage& image)
{
    if (image.rgb.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 3)
        throw InputError("encodePng: the buffer does not match the image size");
    return encodePngPixels(image.width, image.height, 3, image.rgb.data());
}

std::string encodeGrayPng(int width, int height, const std::vector<uint8_t>& gray)
{
    if (width <= 0 || height <= 0 || gray.size() != std::size_t(width) * std::size_t(height))
        throw InputError("encodeGrayPng: the buffer does not match the image size");
    return encodePngPixels(width, height, 1, gray.data());
}

void writePng(const std::string& path, const RgbImage& image)
{
    std::string png;
    try {
        png = encodePng(image);
    } catch (const InputError& e) {
        throw InputError(path + ": " + e.what());
    }
    writeAtomically(path, [&](const std::string& tmp) { writeFileBytes(tmp, png.data(), png.size()); });
}

namespace {

uint32_t readU32(const unsigned char* p)
{
    return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | uint32_t(p[3]);
}

/// Reverses PNG filtering (filter method 0, types 0-4) of `rows` rows of `rowBytes` bytes
/// with `bpp` bytes per pixel, each preceded by its filter type byte, into `out`.
/// @return false for an unknown filter type
bool unfilterRows(const unsigned char* in, std::size_t rowBytes, std::size_t rows, std::size_t bpp, uint8_t* out)
{
    for (std::size_t y = 0; y < rows; ++y) {
        const unsigned char* src = in + y * (rowBytes + 1);
        uint8_t* row = out + y * rowBytes;
        const uint8_t* above = y > 0 ? row - rowBytes : nullptr;
        const unsigned char type = src[0];
        ++src;
        switch (type) {
        case 0:
            std::memcpy(row, src, rowBytes);
            break;
        case 1:
            for (std::size_t i = 0; i < rowBytes; ++i)
                row[i] = uint8_t(src[i] + (i >= bpp ? row[i - bpp] : 0));
            break;
        case 2:
            if (!above) std::memcpy(row, src, rowBytes);
            else
                for (std::size_t i = 0; i < rowBytes; ++i) row[i] = uint8_t(src[i] + above[i]);
            break;
        case 3:
            for (std::size_t i = 0; i < rowBytes; ++i) {
                const unsigned left = i >= bpp ? row[i - bpp] : 0, up = above ? above[i] : 0;
                row[i] = uint8_t(src[i] + ((left + up) >> 1));
            }
            break;
        case 4:
            for (std::size_t i = 0; i < rowBytes; ++i) {
                const int a = i >= bpp ? row[i - bpp] : 0, b = above ? above[i] : 0,
                          c = (above && i >= bpp) ? above[i - bpp] : 0;
                const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
                const int predictor = (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
                row[i] = uint8_t(src[i] + predictor);
            }
            break;
        default:
            return false;
        }
    }
    return true;
}

} // namespace

// A file with any chunk that could make libpng's simplified reader (PNG_FORMAT_RGB) return
// other values than the stored ones (gamma, colour space, transparency, palette) is declined.
bool decodePlainRgbPng(const std::string& bytes, RgbImage& out)
{
    const auto* p = reinterpret_cast<const unsigned char*>(bytes.data());
    const std::size_t size = bytes.size();
    if (size < 8 + 25 || std::memcmp(p, "\x89PNG\r\n\x1a\n", 8) != 0) return false;
    std::size_t at = 8;
    uint32_t width = 0, height = 0;
    std::vector<std::pair<const unsigned char*, std::size_t>> idat;
    bool ended = false, idatClosed = false;
    while (!ended) {
        if (size - at < 12) return false;
        const std::size_t length = readU32(p + at);
        const unsigned char* type = p + at + 4;
        if (length > size - at - 12) return false;
        const unsigned char* data = type + 4;
        const bool critical = (type[0] & 0x20) == 0;
        if (critical && crc32_gzip_refl(0, type, 4 + length) != readU32(data + length)) return false;
        const std::string name(reinterpret_cast<const char*>(type), 4);
        if (at == 8) {
            if (name != "IHDR" || length != 13) return false;
            width = readU32(data);
            height = readU32(data + 4);
            // 8 bits, RGB, deflate, filter method 0, no interlace; libpng's default size limit.
            if (data[8] != 8 || data[9] != 2 || data[10] != 0 || data[11] != 0 || data[12] != 0) return false;
            if (width == 0 || height == 0 || width > 1000000u || height > 1000000u) return false;
        } else if (name == "IDAT") {
            if (idatClosed) return false;
            idat.emplace_back(data, length);
        } else {
            if (!idat.empty()) idatClosed = true;
            if (name == "IEND") ended = true;
            else if (name != "tEXt" && name != "zTXt" && name != "iTXt" && name != "tIME" && name != "pHYs")
                return false;
        }
        at += 12 + length;
    }
    const std::size_t rowBytes = std::size_t(width) * 3;
    if ((rowBytes + 1) > (std::size_t(1) << 31) / std::size_t(height)) return false;
    thread_local std::vector<unsigned char> filtered;
    filtered.resize((rowBytes + 1) * std::size_t(height));
    inflate_state s;
    isal_inflate_init(&s);
    s.crc_flag = ISAL_ZLIB;
    s.next_out = filtered.data();
    s.avail_out = static_cast<uint32_t>(filtered.size());
    for (std::size_t k = 0; k < idat.size(); ++k) {
        s.next_in = const_cast<uint8_t*>(idat[k].first);
        s.avail_in = static_cast<uint32_t>(idat[k].second);
        while (s.avail_in > 0 && s.block_state != ISAL_BLOCK_FINISH) {
            const uint32_t inBefore = s.avail_in, outBefore = s.avail_out;
            if (isal_inflate(&s) != ISAL_DECOMP_OK) return false;
            if (s.avail_in == inBefore && s.avail_out == outBefore) return false;  // no progress
        }
        // Data after the end of the zlib stream: left to libpng's rules.
        if (s.block_state == ISAL_BLOCK_FINISH && (s.avail_in > 0 || k + 1 < idat.size())) return false;
    }
    if (s.block_state != ISAL_BLOCK_FINISH || s.avail_out != 0) return false;
    out.width = int(width);
    out.height = int(height);
    out.rgb.resize(rowBytes * std::size_t(height));
    return unfilterRows(filtered.data(), rowBytes, std::size_t(height), 3, out.rgb.data());
}

RgbImage readPng(const std::string& path)
{
    // The file is read once: decoded here when plain, else given to libpng from memory.
    std::ifstream in(path, std::ios::binary | std::ios::ate);
    if (!in) throw InputError(path + ": cannot open for reading");
    std::string bytes(static_cast<std::size_t>(std::max<std::streamoff>(0, in.tellg())), '\0');
    in.seekg(0);
    if (!in.read(bytes.data(), static_cast<std::streamsize>(bytes.size())))
        throw InputError(path + ": cannot read");
    RgbImage out;
    if (decodePlainRgbPng(bytes, out)) return out;
    png_image img{};
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&img, bytes.data(), bytes.size()))
        throw InputError(path + ": cannot read PNG: " + img.message);
    img.format = PNG_FORMAT_RGB;
    out.width = static_cast<int>(img.width);
    out.height = static_cast<int>(img.height);
    out.rgb.resize(PNG_IMAGE_SIZE(img));
    if (!png_image_finish_read(&img, nullptr, out.rgb.data(), 0, nullptr))
        throw InputError(path + ": cannot read PNG: " + img.message);
    return out;
}

} // namespace flyover
