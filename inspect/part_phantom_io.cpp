/// @file part_phantom_io.cpp
/// @brief Writing the part phantom and its truth (see part_phantom_io.h).
#include "inspect/part_phantom_io.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"
#include "volume/image.h"
#include "volume/slab_writer.h"

namespace flyover {

namespace {

nlohmann::json vec(const Vec3d& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

} // namespace

nlohmann::json partTruthToJson(const PartTruth& t)
{
    nlohmann::json voids = nlohmann::json::array();
    for (const PartVoidTruth& v : t.voids)
        voids.push_back({{"id", v.id},
                         {"kind", v.kind},
                         {"internal", v.internal},
                         {"centroid_lps_mm", vec(v.centroidLps)},
                         {"volume_mm3", v.volumeMm3},
                         {"equivalent_diameter_mm", v.equivalentDiameterMm},
                         {"max_extent_mm", v.maxExtentMm},
                         {"voxels", v.voxels},
                         {"shape_center_lps_mm", vec(v.centerLps)},
                         {"shape_semi_axes_voxels", vec(v.semiAxesVoxels)}});
    return {{"schema", "flyover.part_truth/1"},
            {"world_frame", WORLD_FRAME},
            {"size", t.geometry.size[0]},
            {"voxel_mm", t.geometry.spacingMm.x},
            {"origin_lps_mm", vec(t.geometry.originMm)},
            {"seed", t.params.seed},
            {"grey", {{"air", t.params.airGrey},
                      {"material", t.params.materialGrey},
                      {"noise_sigma", t.params.noiseSigma},
                      {"blur_voxels", t.params.blurVoxels}}},
            {"material_volume_mm3", t.materialVolumeMm3},
            {"internal_void_volume_mm3", t.internalVoidVolumeMm3},
            {"porosity_percent", t.porosityPercent},
            {"voids", voids},
            {"definitions",
             "volumes are partial volumes of the voxelised shapes (sum of voxel fractions); voxels: air "
             "fraction >= 0.5; max extent: largest distance between centres of those voxels; porosity = internal "
             "voids / (material + internal voids) x 100; open_crack is joined to the outside air (not internal)"}};
}

int parsePartSize(const std::string& text)
{
    std::size_t used = 0;
    int n = 0;
    try {
        n = std::stoi(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (used == 0 || used != text.size() || n < 112 || n > 2048)
        throw ParameterError("--size: with --part, a number of voxels from 112 to 2048 (got '" + text + "')");
    return n;
}

PartTruth writePartPhantom(const PartPhantomParams& params, const std::string& ctPath, const std::string& truthPath,
                           Progress* progress)
{
    const int64_t n = params.size;
    ImageGeometry g;
    g.size = {n, n, n};
    g.spacingMm = {params.voxelMm, params.voxelMm, params.voxelMm};
    const double c = 0.5 * static_cast<double>(n - 1);
    g.originMm = {-c * params.voxelMm, -c * params.voxelMm, -c * params.voxelMm};
    if (params.size < 112 || params.size > 2048)
        throw ParameterError("--size: the part phantom takes 112..2048 voxels (got " + std::to_string(params.size) + ")");
    SlabWriter writer(ctPath, g);
    const PartTruth truth = generatePartPhantom(
        params, [&](int64_t, const std::vector<uint16_t>& slice) { writer.writeSlice(slice.data()); }, progress);
    writer.finish();
    if (!truthPath.empty()) writeJson(truthPath, partTruthToJson(truth));
    return truth;
}

} // namespace flyover
