// Image reading and writing through ITK's IO: the one place in flyover that includes ITK.
// IO factories are registered explicitly (instead of ITK_USE_FILE's generated manager), so
// only the formats listed here exist, and ITK's global definitions stay out of other code.

#include "volume/image_io.h"

#include "volume/error.h"

#include <itkGDCMImageIO.h>
#include <itkGDCMImageIOFactory.h>
#include <itkGDCMSeriesFileNames.h>
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkImageSeriesReader.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;

namespace flyover {

namespace {

void registerImageIO()
{
    static std::once_flag once;
    std::call_once(once, [] {
        itk::NiftiImageIOFactory::RegisterOneFactory();
        itk::NrrdImageIOFactory::RegisterOneFactory();
        itk::MetaImageIOFactory::RegisterOneFactory();
        itk::GDCMImageIOFactory::RegisterOneFactory();
    });
}

/// ITK's exception descriptions span several lines; keep the first meaningful one.
std::string oneLine(const std::string& text)
{
    std::istringstream in(text);
    std::string line, best;
    while (std::getline(in, line)) {
        line.erase(0, line.find_first_not_of(" \t"));
        if (!line.empty()) { best = line; break; }
    }
    return best.empty() ? text : best;
}

template <typename ItkImage>
ImageGeometry geometryOf(const ItkImage& image)
{
    ImageGeometry g;
    const auto region = image.GetLargestPossibleRegion();
    for (int c = 0; c < 3; ++c) {
        g.size[c] = static_cast<int64_t>(region.GetSize()[c]);
        g.spacingMm[c] = image.GetSpacing()[c];
        g.originMm[c] = image.GetOrigin()[c];
        for (int r = 0; r < 3; ++r) g.direction[r][c] = image.GetDirection()[r][c];
    }
    return g;
}

void validateGeometry(const ImageGeometry& g, const std::string& path)
{
    for (int c = 0; c < 3; ++c) {
        if (g.size[c] < 1)
            throw InputError(path + ": image has an empty dimension");
        if (!(g.spacingMm[c] > 0) || !std::isfinite(g.spacingMm[c])) {
            std::ostringstream os;
            os << path << ": voxel spacing along axis " << c << " is " << g.spacingMm[c]
               << " mm; expected a positive finite value";
            throw InputError(os.str());
        }
        if (!std::isfinite(g.originMm[c]))
            throw InputError(path + ": image origin is not finite");
    }
    // Direction cosines must be orthonormal, or world positions are meaningless.
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            double d = 0;
            for (int r = 0; r < 3; ++r) d += g.direction[r][a] * g.direction[r][b];
            if (!(std::fabs(d - (a == b ? 1.0 : 0.0)) < 1e-3))
                throw InputError(path + ": direction cosines are not orthonormal");
        }
}

using FloatImage = itk::Image<float, 3>;

Image3<float> toImage3(const FloatImage& image, const std::string& path)
{
    Image3<float> out;
    out.geometry = geometryOf(image);
    validateGeometry(out.geometry, path);
    const float* buf = image.GetBufferPointer();
    out.voxels.assign(buf, buf + out.geometry.voxelCount());
    const auto bad = std::find_if(out.voxels.begin(), out.voxels.end(),
                                  [](float v) { return !std::isfinite(v); });
    if (bad != out.voxels.end()) {
        const int64_t n = bad - out.voxels.begin();
        const auto& s = out.geometry.size;
        std::ostringstream os;
        os << path << ": voxel (" << n % s[0] << "," << (n / s[0]) % s[1] << ","
           << n / (s[0] * s[1]) << ") is " << *bad << "; NaN and Inf voxels are not allowed";
        throw InputError(os.str());
    }
    return out;
}

Image3<float> readDicomSeries(const std::string& dir)
{
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(true);
    names->SetDirectory(dir);
    const auto& uids = names->GetSeriesUIDs();
    if (uids.empty()) throw InputError(dir + ": no DICOM series found in the directory");
    // The series with the most slices.
    std::string best;
    std::size_t bestCount = 0;
    for (const auto& uid : uids) {
        const std::size_t n = names->GetFileNames(uid).size();
        if (n > bestCount) { bestCount = n; best = uid; }
    }
    if (bestCount < 2)
        throw InputError(dir + ": the DICOM series has a single slice; a 3D scan is needed");
    auto reader = itk::ImageSeriesReader<FloatImage>::New();
    reader->SetImageIO(itk::GDCMImageIO::New());
    reader->SetFileNames(names->GetFileNames(best));
    reader->Update();
    return toImage3(*reader->GetOutput(), dir);
}

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
        auto writer = itk::ImageFileWriter<ItkImage>::New();
        writer->SetFileName(tmp.string());
        writer->SetInput(itkImage);
        writer->SetUseCompression(true);
        writer->Update();
    } catch (const itk::ExceptionObject& e) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + oneLine(e.GetDescription()));
    }
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) {
        fs::remove(tmp, ec);
        throw InputError(path + ": cannot write image: " + ec.message());
    }
}

} // namespace

Image3<float> readImage(const std::string& path)
{
    registerImageIO();
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError(path + ": no such file or directory");
    try {
        if (fs::is_directory(path, ec)) return readDicomSeries(path);

        itk::ImageIOBase::Pointer io = itk::ImageIOFactory::CreateImageIO(
            path.c_str(), itk::CommonEnums::IOFileMode::ReadMode);
        if (!io)
            throw InputError(path + ": not a readable image (supported: NIfTI .nii/.nii.gz, "
                                    "NRRD .nrrd/.nhdr, MetaImage .mha/.mhd, DICOM directory)");
        io->SetFileName(path);
        io->ReadImageInformation();
        const unsigned dims = io->GetNumberOfDimensions();
        unsigned effective = 0;
        for (unsigned d = 0; d < dims; ++d) effective += io->GetDimensions(d) > 1 ? 1 : 0;
        if (dims < 3 || effective < 3) {
            std::ostringstream os;
            os << path << ": image is " << effective << "D; a 3D volume is needed";
            throw InputError(os.str());
        }
        if (dims > 3) {
            for (unsigned d = 3; d < dims; ++d)
                if (io->GetDimensions(d) > 1)
                    throw InputError(path + ": image has more than 3 dimensions (a time series?)");
        }
        if (io->GetNumberOfComponents() != 1)
            throw InputError(path + ": image has " + std::to_string(io->GetNumberOfComponents()) +
                             " components per voxel; a scalar image is needed");
        auto reader = itk::ImageFileReader<FloatImage>::New();
        reader->SetImageIO(io);
        reader->SetFileName(path);
        reader->Update();
        return toImage3(*reader->GetOutput(), path);
    } catch (const itk::ExceptionObject& e) {
        throw InputError(path + ": cannot read image: " + oneLine(e.GetDescription()));
    }
}

void writeImage(const Image3<int16_t>& image, const std::string& path) { writeImageImpl(image, path); }
void writeImage(const Image3<uint8_t>& image, const std::string& path) { writeImageImpl(image, path); }

} // namespace flyover
