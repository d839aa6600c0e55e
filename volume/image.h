/// @file image.h
/// @brief A dense 3D image with its scan geometry, as read from or written to a file.
///
/// Geometry follows ITK and DICOM exactly: the world frame is LPS (x to the patient's
/// Left, y to Posterior, z to Superior), in millimetres, and the centre of voxel
/// (i,j,k) lies at  origin + direction * (spacing ⊙ (i,j,k)).  `direction` holds the
/// direction cosines as columns (column c is the world direction of index axis c).
#pragma once

#include "volume/vec3.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace flyover {

/// World frame named in every JSON artifact.
inline constexpr const char* WORLD_FRAME = "LPS";

/// 3x3 matrix, row-major: m[r][c].
using Mat3d = std::array<std::array<double, 3>, 3>;

inline constexpr Mat3d identityMat3() { return {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}}; }

struct ImageGeometry {
    std::array<int64_t, 3> size{0, 0, 0};  ///< voxels along i, j, k
    Vec3d spacingMm{1, 1, 1};              ///< voxel pitch along i, j, k (mm, > 0)
    Vec3d originMm{0, 0, 0};               ///< world position of voxel (0,0,0)'s centre (LPS mm)
    Mat3d direction = identityMat3();      ///< columns: world directions of the index axes

    int64_t voxelCount() const { return size[0] * size[1] * size[2]; }

    /// World position (LPS mm) of a continuous index position.
    Vec3d worldFromIndex(const Vec3d& ijk) const
    {
        const Vec3d s{ijk.x * spacingMm.x, ijk.y * spacingMm.y, ijk.z * spacingMm.z};
        Vec3d w = originMm;
        for (int r = 0; r < 3; ++r)
            w[r] += direction[r][0] * s.x + direction[r][1] * s.y + direction[r][2] * s.z;
        return w;
    }

    /// Continuous index position of a world position (LPS mm); inverse of worldFromIndex
    /// (direction cosines are orthonormal, so the inverse is the transpose).
    Vec3d indexFromWorld(const Vec3d& world) const
    {
        const Vec3d d = world - originMm;
        Vec3d ijk;
        for (int c = 0; c < 3; ++c)
            ijk[c] = (direction[0][c] * d.x + direction[1][c] * d.y + direction[2][c] * d.z) /
                     spacingMm[c];
        return ijk;
    }
};

/// A dense image: x (i) fastest, then j, then k, as in NIfTI and ITK buffers.
template <typename T>
struct Image3 {
    ImageGeometry geometry;
    std::vector<T> voxels;

    std::size_t linearIndex(int64_t i, int64_t j, int64_t k) const
    {
        return static_cast<std::size_t>(i + geometry.size[0] * (j + geometry.size[1] * k));
    }
    T& at(int64_t i, int64_t j, int64_t k) { return voxels[linearIndex(i, j, k)]; }
    const T& at(int64_t i, int64_t j, int64_t k) const { return voxels[linearIndex(i, j, k)]; }
};

/// A 3D scan opened for reading a few slices at a time (k is the slowest index), so that a
/// converter never holds the whole volume as float. Header, geometry and slice order are
/// read and checked when the source is opened (volume/image_io.h: openImage); voxels are
/// read on demand by readSlices().
///
/// Slice positions: `geometry()` is the nominal lattice (for a DICOM series: the median
/// slice step). When isRegular() is false (a DICOM series with accepted gaps or uneven
/// steps, or with gantry tilt), slice k's voxel (0,0) truly lies at sliceOriginsMm()[k],
/// and a consumer must sample at those positions rather than on the nominal lattice.
class ImageSource {
public:
    virtual ~ImageSource() = default;

    /// The file or folder, as named in messages.
    const std::string& name() const { return mName; }
    /// Size and nominal geometry: index -> LPS world millimetres.
    const ImageGeometry& geometry() const { return mGeometry; }
    /// True when slice k lies exactly at geometry().worldFromIndex({0,0,k}).
    bool isRegular() const { return mRegular; }
    /// World position (LPS mm) of voxel (0,0,k)'s centre, one per slice, strictly increasing
    /// along the slice normal (direction column 2).
    const std::vector<Vec3d>& sliceOriginsMm() const { return mSliceOriginsMm; }
    /// What the reader accepted or corrected that the user should hear about (one line each).
    const std::vector<std::string>& warnings() const { return mWarnings; }
    /// Format, library and read mode, e.g. "NIfTI via ITK NiftiImageIO, streamed by slab".
    const std::string& description() const { return mDescription; }
    /// Bytes the source holds for the whole scan while open (0 when it streams).
    int64_t heldBytes() const { return mHeldBytes; }

    /// Reads slices [k0, k1) as float (HU after any rescale slope/intercept), x fastest, then
    /// y, then k, into `out` (size[0] * size[1] * (k1 - k0) values). Slices are best read in
    /// increasing k.
    /// @throw InputError naming the file: truncated or undecodable data, NaN or Inf voxels.
    virtual void readSlices(int64_t k0, int64_t k1, float* out) = 0;

protected:
    ImageSource() = default;
    ImageSource(const ImageSource&) = delete;
    ImageSource& operator=(const ImageSource&) = delete;

    std::string mName;
    ImageGeometry mGeometry;
    bool mRegular = true;
    std::vector<Vec3d> mSliceOriginsMm;
    std::vector<std::string> mWarnings;
    std::string mDescription;
    int64_t mHeldBytes = 0;
};

/// A dense float image in memory as an ImageSource (the image must outlive it).
class MemoryImageSource final : public ImageSource {
public:
    explicit MemoryImageSource(const Image3<float>& image, const std::string& name = "image")
        : mImage(image)
    {
        mName = name;
        mGeometry = image.geometry;
        mDescription = "dense float image in memory";
        mHeldBytes = static_cast<int64_t>(image.voxels.size() * sizeof(float));
    }
    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const std::size_t perSlice = static_cast<std::size_t>(mGeometry.size[0] * mGeometry.size[1]);
        std::memcpy(out, mImage.voxels.data() + perSlice * static_cast<std::size_t>(k0),
                    perSlice * static_cast<std::size_t>(k1 - k0) * sizeof(float));
    }

private:
    const Image3<float>& mImage;
};

} // namespace flyover
