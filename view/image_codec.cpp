#include "view/image_codec.h"

#include <turbojpeg.h>

#include <memory>
#include <stdexcept>

namespace flyover {

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
