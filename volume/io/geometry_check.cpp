// Header geometry checks: see geometry_check.h.

#include "volume/io/geometry_check.h"

#include "volume/error.h"
#include "volume/io/pixel_convert.h"

#include <cmath>
#include <sstream>
#include <vector>

namespace flyover::imageio {

void validateGeometry(const ImageGeometry& g, const std::string& path)
{
    static const char* AXIS[3] = {"i (x)", "j (y)", "k (z)"};
    for (int c = 0; c < 3; ++c) {
        if (g.size[c] < 1) throw InputError(path + ": image has an empty dimension");
        if (!(g.spacingMm[c] > 0) || !std::isfinite(g.spacingMm[c])) {
            std::ostringstream os;
            os << path << ": voxel spacing along " << AXIS[c] << " is " << g.spacingMm[c]
               << " mm; expected a positive finite value";
            throw InputError(os.str());
        }
        if (!std::isfinite(g.originMm[c])) throw InputError(path + ": image origin is not finite");
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

ImageGeometry checkHeader(itk::ImageIOBase& io, const std::string& path)
{
    const unsigned dims = io.GetNumberOfDimensions();
    std::vector<uint64_t> sizes;
    for (unsigned d = 0; d < dims; ++d) sizes.push_back(io.GetDimensions(d));
    std::string sizeList;
    for (auto s : sizes) sizeList += (sizeList.empty() ? "" : " x ") + std::to_string(s);
    if (dims < 3 || sizes[0] < 2 || sizes[1] < 2 || sizes[2] < 2)
        throw InputError(path + ": image is 2D (" + sizeList + "); a 3D volume is needed");
    for (unsigned d = 3; d < dims; ++d)
        if (sizes[d] > 1)
            throw InputError(path + ": image is " + std::to_string(dims) + "D (" + sizeList +
                             "), e.g. a time series; a single 3D volume is needed");
    if (io.GetPixelType() != itk::IOPixelEnum::SCALAR || io.GetNumberOfComponents() != 1)
        throw InputError(path + ": pixel type is " + itk::ImageIOBase::GetPixelTypeAsString(io.GetPixelType()) +
                         " with " + std::to_string(io.GetNumberOfComponents()) +
                         " components per voxel; a scalar (grey-value) image is needed");
    if (componentBytes(io.GetComponentType()) == 0)
        throw InputError(path + ": voxel type " + itk::ImageIOBase::GetComponentTypeAsString(io.GetComponentType()) +
                         " is not supported (integers up to 64 bits, float and double are)");
    // Sizes are unsigned 64-bit: a hostile header can make their product wrap around, and the
    // data size check with it. 2^56 bytes is far beyond any file.
    long double totalBytes = static_cast<long double>(componentBytes(io.GetComponentType()));
    for (auto sz : sizes) totalBytes *= static_cast<long double>(sz);
    if (totalBytes > static_cast<long double>(int64_t(1) << 56))
        throw InputError(path + ": header describes " + sizeList + " voxels, more than any file holds");
    ImageGeometry g;
    for (int c = 0; c < 3; ++c) {
        g.size[c] = static_cast<int64_t>(sizes[c]);
        g.spacingMm[c] = io.GetSpacing(c);
        g.originMm[c] = io.GetOrigin(c);
        const auto dir = io.GetDirection(c);
        for (int r = 0; r < 3; ++r) g.direction[r][c] = r < int(dir.size()) ? dir[r] : 0.0;
    }
    validateGeometry(g, path);
    return g;
}

} // namespace flyover::imageio
