// `flyover export --lumen`: the lumen level set rasterised on the original scan's lattice.
#include "colon/export.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"
#include "volume/image_io.h"
#include "colon/lumen_mask.h"

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

const json* stageReport(const json& manifest, const std::string& stage)
{
    if (!manifest.is_object() || !manifest.contains("stages")) return nullptr;
    for (const auto& e : manifest["stages"])
        if (e.value("stage", "") == stage && e.contains("report")) return &e["report"];
    return nullptr;
}

Vec3d vec3(const json& j) { return {j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()}; }

/// A 3x3 matrix written as rows (as the stage reports write direction cosines).
Mat3d matrix(const json& rows)
{
    Mat3d m{};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) m[r][c] = rows.at(r).at(c).get<double>();
    return m;
}

/// The original scan's lattice: the ingest report's input geometry, or for a study made from
/// a mask alone, the mask's geometry recorded by the segment stage.
ImageGeometry originalGeometry(const json& manifest, const std::string& studyDir)
{
    ImageGeometry g;
    try {
        const json* ingest = stageReport(manifest, "ingest");
        const json* segment = stageReport(manifest, "segment");
        if (ingest && ingest->contains("input_origin_mm") && ingest->contains("input_direction")) {
            g.size = ingest->at("input_size").get<std::array<int64_t, 3>>();
            g.spacingMm = vec3(ingest->at("input_spacing_mm"));
            g.originMm = vec3(ingest->at("input_origin_mm"));
            g.direction = matrix(ingest->at("input_direction"));
            return g;
        }
        if (segment && segment->contains("mask")) {
            const json& m = segment->at("mask").at("geometry");
            g.size = m.at("size").get<std::array<int64_t, 3>>();
            g.spacingMm = vec3(m.at("spacing_mm"));
            g.originMm = vec3(m.at("origin_mm"));
            g.direction = matrix(m.at("direction"));
            return g;
        }
    } catch (const json::exception& e) {
        throw InputError(studyDir + "/manifest.json: unreadable scan geometry (" + e.what() + ")");
    }
    throw InputError(studyDir + ": the manifest records no scan geometry (run the study again: "
                                "'flyover run' writes it with ingest, or with segment for --mask alone)");
}

} // namespace

void exportLumen(const std::string& studyDir, const std::string& outPath)
{
    const fs::path dir(studyDir);
    if (!fs::exists(dir / "manifest.json"))
        throw InputError(studyDir + ": not a flyover study (no manifest.json; run 'flyover run' first)");
    if (!fs::exists(dir / "lumen.vdb"))
        throw InputError(studyDir + ": no lumen.vdb (run 'flyover run --until segment' first)");
    const ImageGeometry geometry = originalGeometry(readJson((dir / "manifest.json").string()), studyDir);
    const auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid((dir / "lumen.vdb").string(), "lumen_sdf"));
    if (!sdf) throw InputError((dir / "lumen.vdb").string() + ": lumen_sdf is not a float grid");
    writeImage(rasterizeLumen(*sdf, geometry), outPath);
}

} // namespace flyover
