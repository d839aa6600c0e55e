#include "volume/ct_slice.h"

#include "volume/error.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace flyover {

SliceGeometry sliceGeometry(const std::string& plane, const Vec3d& q, const Vec3d& lo, const Vec3d& hi, double pixelMm)
{
    if (!(pixelMm > 0) || !std::isfinite(pixelMm)) throw ParameterError("slice pixel: must be a finite number > 0 mm");
    SliceGeometry g;
    g.plane = plane;
    double colExtent = 0, rowExtent = 0;
    if (plane == "axial") {
        g.colDir = {1, 0, 0}, g.rowDir = {0, 1, 0};
        g.originMm = {lo.x, lo.y, q.z};
        colExtent = hi.x - lo.x, rowExtent = hi.y - lo.y;
    } else if (plane == "coronal") {
        g.colDir = {1, 0, 0}, g.rowDir = {0, 0, -1};
        g.originMm = {lo.x, q.y, hi.z};
        colExtent = hi.x - lo.x, rowExtent = hi.z - lo.z;
    } else if (plane == "sagittal") {
        g.colDir = {0, 1, 0}, g.rowDir = {0, 0, -1};
        g.originMm = {q.x, lo.y, hi.z};
        colExtent = hi.y - lo.y, rowExtent = hi.z - lo.z;
    } else {
        throw ParameterError("plane: must be axial, coronal or sagittal");
    }
    g.pixelMm = pixelMm;
    g.width = int(std::floor(std::max(colExtent, 0.0) / pixelMm)) + 1;
    g.height = int(std::floor(std::max(rowExtent, 0.0) / pixelMm)) + 1;
    return g;
}

SliceImage sampleSlice(const openvdb::FloatGrid& hu, const SliceGeometry& g, double window, double level)
{
    if (!(window > 0) || !std::isfinite(window)) throw ParameterError("window: must be a finite number > 0");
    if (!std::isfinite(level)) throw ParameterError("level: must be a finite number");
    SliceImage out;
    out.geometry = g;
    out.gray.assign(std::size_t(g.width) * std::size_t(g.height), 0);
    const double lo = level - 0.5 * window;
    tbb::parallel_for(0, g.height, [&](int r) {
        openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> sampler(
            hu.getConstAccessor(), hu.transform());
        for (int c = 0; c < g.width; ++c) {
            const Vec3d w = g.originMm + g.colDir * (c * g.pixelMm) + g.rowDir * (r * g.pixelMm);
            const double v = std::clamp((sampler.wsSample(openvdb::Vec3d(w.x, w.y, w.z)) - lo) / window, 0.0, 1.0);
            out.gray[std::size_t(r) * std::size_t(g.width) + std::size_t(c)] = uint8_t(std::lround(v * 255.0));
        }
    });
    return out;
}

} // namespace flyover
