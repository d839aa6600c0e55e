// Writing dense images through ITK (writeImage in volume/image_io.h): to a temporary name in
// the same folder, then an atomic rename.

#include "volume/image_io.h"

#include "volume/error.h"
#include "volume/io/itk_console.h"

#include <itkImage.h>
#include <itkImageFileWriter.h>

#include <filesystem>

#include <unistd.h>

namespace fs = std::filesystem;

namespace flyover {

namespace {

using imageio::CapturedOutput;
using imageio::itkReason;
using imageio::registerImageIO;

template <typename T>
void writeImageImpl(const Image3<T>& image, const std::string& path)
{
    registerImageIO();
    using ItkImage = itk::Image<T, 3>;
    auto itkImage = ItkImage::New();
    typename ItkImage::RegionType region;
    typename ItkImage::SpacingType spacing;
    typename ItkImage::PointType origin;
    typename ItkImage::DirectionType direction;
    const auto& g = image.geometry;
    for (int c = 0; c < 3; ++c) {
        region.SetSize(c, static_cast<itk::SizeValueType>(g.size[c]));
        spacing[c] = g.spacingMm[c];
        origin[c] = g.originMm[c];
        for (int r = 0; r < 3; ++r) direction[r][c] = g.direction[r][c];
    }
    if (static_cast<int64_t>(image.voxels.size()) != g.voxelCount())
        throw InputError(path + ": image buffer size does not match its dimensions");
    itkImage->SetRegions(region);
    itkImage->SetSpacing(spacing);
    itkImage->SetOrigin(origin);
    itkImage->SetDirection(direction);
    // ITK wants a mutable buffer it does not own.
    itkImage->GetPixelContainer()->SetImportPointer(const_cast<T*>(image.voxels.data()),
                                                    image.voxels.size(), false);

    // Temporary name in the same folder with the same extension(s), then an atomic rename.
    const fs::path target(path);
    const std::string name = target.filename().string();
    const fs::path tmp = target.parent_path() /
                         (".tmp-" + std::to_string(::getpid()) + "-" + name);
    try {
        CapturedOutput capture;
        auto writer = itk::ImageFileWriter<ItkImage>::New();
        writer->SetFileName(tmp.string());
        writer->SetInput(itkImage);
        writer->SetUseCompression(true);
        writer->Update();
    } catch (const itk::ExceptionObject& e) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + itkReason(e));
    }
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) {
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + ec.message());
    }
}

} // namespace

void writeImage(const Image3<int16_t>& image, const std::string& path) { writeImageImpl(image, path); }
void writeImage(const Image3<uint8_t>& image, const std::string& path) { writeImageImpl(image, path); }

} // namespace flyover
