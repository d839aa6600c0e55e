#include "inspect/inspect_params.h"

#include "pipeline/param_json.h"

#include "volume/error.h"

#include <cmath>
#include <limits>
#include <sstream>

namespace flyover {

namespace {

using nlohmann::json;

template <typename V> void visit(PartIngestParams& p, V&& v)
{
    v("voxel_mm", p.voxelMm, "isotropic voxel size in mm (0 = smallest input spacing)");
}
template <typename V> void visit(VoidParams& p, V&& v)
{
    v("threshold", p.threshold, "material is grey value >= this (null = Otsu's threshold of the histogram)");
    v("min_diameter_voxels", p.minDiameterVoxels,
      "voids with an equivalent diameter below this (voxels) are counted, not listed");
}
template <typename V> void visit(PartSurfaceParams& p, V&& v)
{
    v("smooth_iterations", p.smoothIterations, "Taubin lambda|mu iterations on the surfaces (0 = none)");
    v("smooth_pass_band", p.smoothPassBand, "Taubin pass band k_PB in (0, 1)");
}
template <typename V> void visit(PartRenderParams& p, V&& v)
{
    v("overview_px", p.overviewPx, "size of each overview panel (pixels, square)");
    v("supersample", p.supersample, "n x n rays per pixel");
    v("smooth_shading", p.smoothShading, "shade with interpolated vertex normals");
    v("depth_cue", p.depthCue, "darken with depth");
    v("video", p.video, "turntable MP4 in turntable/ (needs the ffmpeg program)");
    v("turntable_frames", p.turntableFrames, "frames per turn of the turntable");
    v("video_fps", p.videoFps, "turntable frame rate (frames per second)");
    v("video_px", p.videoPx, "size of each turntable panel (pixels, square)");
}

template <typename F> void visitSection(InspectParams& p, const std::string& section, F&& f)
{
    if (section == "ingest") return f(p.ingest);
    if (section == "voids") return f(p.voids);
    if (section == "surfaces") return f(p.surfaces);
    if (section == "render") return f(p.render);
    std::string known;
    for (const auto& s : inspectSections()) known += (known.empty() ? "" : ", ") + s;
    throw ParameterError("unknown inspect stage '" + section + "' (stages: " + known + ")");
}

/// A double that may be NaN (voids.threshold: null = Otsu); other doubles are finite.
json toJsonValue(double v) { return std::isnan(v) ? json(nullptr) : json(v); }
json toJsonValue(int v) { return v; }
json toJsonValue(bool v) { return v; }

void fromJsonValue(const json& j, double& out, const std::string& name)
{
    if (j.is_null() && name == "voids.threshold") {
        out = std::numeric_limits<double>::quiet_NaN();
        return;
    }
    param_json::readNumber(j, out, name);
}
void fromJsonValue(const json& j, int& out, const std::string& name) { param_json::readInteger(j, out, name); }
void fromJsonValue(const json& j, bool& out, const std::string& name) { param_json::readBool(j, out, name); }

template <typename P> void sectionFromJson(P& p, const json& j, const std::string& section)
{
    param_json::readObject(
        p, j, section, "inspect " + section, [](auto& q, auto&& f) { visit(q, f); },
        [](const json& v, auto& out, const std::string& name) { fromJsonValue(v, out, name); });
}

} // namespace

const std::vector<std::string>& inspectSections()
{
    static const std::vector<std::string> names{"ingest", "voids", "surfaces", "render"};
    return names;
}

nlohmann::json inspectParamsToJson(const InspectParams& params, const std::string& section)
{
    InspectParams copy = params;
    json j = json::object();
    visitSection(copy, section, [&](auto& p) {
        visit(p, [&](const char* key, auto& value, const char*) { j[key] = toJsonValue(value); });
    });
    return j;
}

int inspectSectionVersion(const std::string& section)
{
    if (section == "ingest") return PartIngestParams::VERSION;
    if (section == "voids") return VoidParams::VERSION;
    if (section == "surfaces") return PartSurfaceParams::VERSION;
    if (section == "render") return PartRenderParams::VERSION;
    throw ParameterError("unknown inspect stage '" + section + "'");
}

void applyInspectParamsJson(InspectParams& params, const nlohmann::json& config, const std::string& source)
{
    if (!config.is_object()) throw ParameterError(source + ": expected a JSON object of stages");
    for (auto it = config.begin(); it != config.end(); ++it) {
        try {
            visitSection(params, it.key(), [&](auto& p) { sectionFromJson(p, it.value(), it.key()); });
        } catch (const ParameterError& e) {
            throw ParameterError(source + ": " + e.what());
        }
    }
}

void applyInspectAssignment(InspectParams& params, const std::string& assignment)
{
    const auto eq = assignment.find('=');
    const auto dot = assignment.find('.');
    if (eq == std::string::npos || dot == std::string::npos || dot > eq)
        throw ParameterError("--set '" + assignment + "': expected stage.parameter=value");
    const std::string section = assignment.substr(0, dot);
    const std::string name = assignment.substr(dot + 1, eq - dot - 1);
    const std::string text = assignment.substr(eq + 1);
    json value = json::parse(text, nullptr, /*allow_exceptions=*/false);
    if (value.is_discarded()) value = text;
    applyInspectParamsJson(params, json{{section, json{{name, value}}}}, "--set " + section + "." + name);
}

void validateInspectParams(const InspectParams& p)
{
    auto require = [](bool ok, const std::string& name, const std::string& what) {
        if (!ok) throw ParameterError(name + ": " + what);
    };
    require(p.ingest.voxelMm >= 0, "ingest.voxel_mm", "must be >= 0 (0 = smallest input spacing)");
    require(std::isnan(p.voids.threshold) || std::isfinite(p.voids.threshold), "voids.threshold",
            "must be a finite grey value or null (Otsu)");
    require(p.voids.minDiameterVoxels >= 0 && p.voids.minDiameterVoxels <= 1000, "voids.min_diameter_voxels",
            "must be in [0, 1000]");
    require(p.surfaces.smoothIterations >= 0 && p.surfaces.smoothIterations <= 1000, "surfaces.smooth_iterations",
            "must be in [0, 1000]");
    require(p.surfaces.smoothPassBand > 0 && p.surfaces.smoothPassBand < 1, "surfaces.smooth_pass_band",
            "must be in (0, 1)");
    require(p.render.overviewPx >= 64 && p.render.overviewPx <= 4096, "render.overview_px", "must be in [64, 4096]");
    require(p.render.supersample >= 1 && p.render.supersample <= 8, "render.supersample", "must be in [1, 8]");
    require(p.render.turntableFrames >= 2 && p.render.turntableFrames <= 3600, "render.turntable_frames",
            "must be in [2, 3600]");
    require(p.render.videoFps >= 1 && p.render.videoFps <= 120, "render.video_fps", "must be in [1, 120]");
    require(p.render.videoPx >= 64 && p.render.videoPx <= 4096, "render.video_px", "must be in [64, 4096]");
}

std::string describeInspectParams()
{
    InspectParams p;
    std::ostringstream os;
    for (const auto& section : inspectSections())
        visitSection(p, section, [&](auto& sp) {
            visit(sp, [&](const char* key, auto& value, const char* help) {
                os << "  " << section << "." << key << " = " << toJsonValue(value).dump() << "\n      " << help
                   << "\n";
            });
        });
    return os.str();
}

} // namespace flyover
