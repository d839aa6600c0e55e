// The stages of a part study, `flyover inspect CT --study DIR` (thesis chapter VII):
// industrial CT of a solid part -> its internal voids (pores, cracks), measured, and shown in
// place by one-sided transparency.
//
//   ingest     ct.vdb             FloatGrid "ct_grey": the grey values as read (any scalar type,
//                                 any range; no HU assumptions), every voxel kept, cubic voxels
//   voids      voids.csv          one row per listed void (LPS mm), fixed header
//              voids.json         schema flyover.voids/1: threshold and its source, porosity,
//                                 small voids, every listed void as in the CSV
//              voids.vdb          BoolGrids "material", "outside_air", Int32Grid "void_labels"
//   surfaces   part_surface.ply   outer surface + each listed void, normals into the material
//              surfaces.json      schema flyover.part_surfaces/1: the face range of each void
//   overviews  overviews/         <view>.png: OST | normal | legend for the six views;
//                                 cameras.json, visibility.json (pixels of each void per view),
//                                 legend.json, legend.png; overview.png = the anterior one
//   turntable  turntable/         turntable.mp4 (OST | normal | legend, one turn about the
//                                 superior axis) and poses.json
// Every file is written atomically; folders are staged and renamed (render_output.h).
#include "inspect/inspect_study.h"
#include "pipeline/ingest_to_vdb.h"

#include "pipeline/artifact_io.h"
#include "pipeline/render_output.h"
#include "render/camera.h"
#include "render/overview.h"
#include "inspect/part_render.h"
#include "render/ray_scene.h"
#include "inspect/part_surface.h"
#include "volume/error.h"
#include "volume/image_io.h"
#include "volume/ingest.h"
#include "inspect/voids.h"

#include <openvdb/tools/Statistics.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#if defined(__GLIBC__)
#include <malloc.h>
#endif
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

/// Hands the pages of freed small blocks back to the system. The CT grid is millions of 2 KB
/// leaves; once freed, glibc keeps their pages, and the mesh (large vectors, mapped apart)
/// cannot reuse them, so the process would hold both.
void releaseFreedMemory()
{
#if defined(__GLIBC__)
    malloc_trim(0);
#endif
}

const char* const CT_GRID = "ct_grey";
const char* const CSV_HEADER = "id,kind,volume_mm3,equivalent_diameter_mm,max_extent_mm,sphericity,"
                               "centroid_x_mm,centroid_y_mm,centroid_z_mm,distance_to_surface_mm";

/// The CT grid: from memory when this run holds it, else from ct.vdb (with `delayed`, each
/// leaf's values read only when first accessed: for a stage that reads a small part of them).
openvdb::FloatGrid::Ptr partGrid(PartRun& run, bool delayed = false)
{
    if (!run.state.hu)
        run.state.hu = openvdb::gridPtrCast<openvdb::FloatGrid>(delayed ? readGridDelayed(run.path("ct.vdb"), CT_GRID)
                                                                         : readGrid(run.path("ct.vdb"), CT_GRID));
    if (!run.state.hu) throw InputError(run.path("ct.vdb") + ": grid " + CT_GRID + " is not a float grid");
    return run.state.hu;
}

std::string fixed(double v, int decimals)
{
    char text[64];
    std::snprintf(text, sizeof text, "%.*f", decimals, v);
    return text;
}

json voidJson(const VoidInfo& v)
{
    return json{{"id", v.id},
                {"kind", v.kind},
                {"volume_mm3", v.volumeMm3},
                {"equivalent_diameter_mm", v.equivalentDiameterMm},
                {"max_extent_mm", v.maxExtentMm},
                {"sphericity", v.sphericity},
                {"centroid_x_mm", v.centroidLps.x},
                {"centroid_y_mm", v.centroidLps.y},
                {"centroid_z_mm", v.centroidLps.z},
                {"distance_to_surface_mm", v.distanceToSurfaceMm},
                {"voxels", v.voxels}};
}

VoidInfo voidFromJson(const json& j)
{
    VoidInfo v;
    v.id = j.at("id").get<int>();
    v.kind = j.at("kind").get<std::string>();
    v.volumeMm3 = j.at("volume_mm3").get<double>();
    v.equivalentDiameterMm = j.at("equivalent_diameter_mm").get<double>();
    v.maxExtentMm = j.at("max_extent_mm").get<double>();
    v.sphericity = j.at("sphericity").get<double>();
    v.centroidLps = Vec3d{j.at("centroid_x_mm").get<double>(), j.at("centroid_y_mm").get<double>(),
                          j.at("centroid_z_mm").get<double>()};
    v.distanceToSurfaceMm = j.at("distance_to_surface_mm").get<double>();
    v.voxels = j.at("voxels").get<int64_t>();
    return v;
}

/// The listed voids of voids.json (the render steps need their sizes only).
std::vector<VoidInfo> readVoidList(const std::string& path)
{
    const json j = readJson(path);
    std::vector<VoidInfo> out;
    try {
        for (const auto& v : j.at("voids")) out.push_back(voidFromJson(v));
    } catch (const json::exception& e) {
        throw InputError(path + ": not a flyover.voids/1 file (" + e.what() + ")");
    }
    return out;
}

/// The voids stage's analysis: from memory when it ran in this run, else from its files.
std::shared_ptr<PartAnalysis> partAnalysis(PartRun& run)
{
    if (run.state.part) return run.state.part;
    auto a = std::make_shared<PartAnalysis>();
    const json j = readJson(run.path("voids.json"));
    a->threshold = j.at("threshold").get<double>();
    a->thresholdSource = j.at("threshold_source").get<std::string>();
    a->voids = readVoidList(run.path("voids.json"));
    a->material = openvdb::gridPtrCast<openvdb::BoolGrid>(readGrid(run.path("voids.vdb"), "material"));
    a->outsideAir = openvdb::gridPtrCast<openvdb::BoolGrid>(readGrid(run.path("voids.vdb"), "outside_air"));
    a->voidLabels = openvdb::gridPtrCast<openvdb::Int32Grid>(readGrid(run.path("voids.vdb"), "void_labels"));
    if (!a->material || !a->outsideAir || !a->voidLabels)
        throw InputError(run.path("voids.vdb") + ": a grid has the wrong type");
    run.state.part = a;
    return a;
}

/// What the render steps draw: the surfaces' scene, the void of every triangle, the colours.
struct PartScene {
    std::unique_ptr<RayScene> scene;
    std::vector<int> faceVoid;            ///< per triangle: 0 = the part's surface, else the void id
    std::vector<Rgb8> faceColours;
    std::vector<VoidInfo> voids;
    SizeColourScale scale;
};

PartScene partScene(PartRun& run)
{
    PartScene ps;
    ps.voids = readVoidList(run.path("voids.json"));
    std::vector<float> xyz;
    std::vector<uint32_t> tris;
    if (!readPlainPly(run.path("part_surface.ply"), xyz, tris))
        throw InputError(run.path("part_surface.ply") + ": not the PLY layout the surfaces stage writes");
    ps.scene = std::make_unique<RayScene>(std::move(xyz), std::move(tris));
    const json s = readJson(run.path("surfaces.json"));
    const std::size_t n = ps.scene->triangleCount();
    ps.faceVoid.assign(n, 0);
    for (const auto& v : s.at("voids")) {
        const int id = v.at("id").get<int>();
        const int64_t first = v.at("first_face").get<int64_t>(), count = v.at("faces").get<int64_t>();
        if (first < 0 || count < 0 || std::size_t(first + count) > n)
            throw InputError(run.path("surfaces.json") + ": void " + std::to_string(id) + "'s faces lie outside the mesh");
        for (int64_t f = first; f < first + count; ++f) ps.faceVoid[std::size_t(f)] = id;
    }
    double lo = std::numeric_limits<double>::infinity(), hi = 0;
    for (const auto& v : ps.voids) {
        lo = std::min(lo, v.equivalentDiameterMm);
        hi = std::max(hi, v.equivalentDiameterMm);
    }
    ps.scale = ps.voids.empty() ? SizeColourScale{1, 1} : SizeColourScale{lo, hi};
    std::vector<Rgb8> voidColour(ps.voids.size() + 1, PART_GREY);
    for (const auto& v : ps.voids)
        if (v.id >= 1 && std::size_t(v.id) < voidColour.size()) voidColour[std::size_t(v.id)] = ps.scale.colour(v.equivalentDiameterMm);
    ps.faceColours.resize(n);
    for (std::size_t f = 0; f < n; ++f) {
        const int id = ps.faceVoid[f];
        ps.faceColours[f] = id > 0 && std::size_t(id) < voidColour.size() ? voidColour[std::size_t(id)] : PART_GREY;
    }
    return ps;
}

RenderOptions partRenderOptions(const PartRenderParams& rp, int px, bool ost)
{
    RenderOptions ro;
    ro.widthPx = ro.heightPx = px;
    ro.ost = ost;
    ro.supersample = rp.supersample;
    ro.smoothShading = rp.smoothShading;
    ro.depthCue = rp.depthCue;
    return ro;
}

/// Pixels of each void (index id) in a hit image, or rays in a list of every ray's hit.
std::vector<int64_t> voidPixels(const std::vector<uint32_t>& primIds, const PartScene& ps)
{
    std::vector<int64_t> count(ps.voids.size() + 1, 0);
    for (const uint32_t prim : primIds)
        if (prim < ps.faceVoid.size()) {
            const int id = ps.faceVoid[prim];
            if (id > 0 && std::size_t(id) < count.size()) ++count[std::size_t(id)];
        }
    return count;
}

/// OST | normal | legend, each panel labelled.
RgbImage comparisonImage(RgbImage ost, RgbImage normal, const SizeColourScale& scale)
{
    const Rgb8 label{240, 240, 240};
    drawText(ost, 8, 8, "OST", label, 2);
    drawText(normal, 8, 8, "normal", label, 2);
    const RgbImage legend = sizeLegendPanel(scale, 96, ost.height);
    return sideBySide(sideBySide(ost, normal), legend);
}

json legendJson(const PartScene& ps)
{
    json stops = json::array();
    for (int i = 0; i <= 4; ++i) {
        const double t = i / 4.0;
        const double mm = ps.scale.maxMm > ps.scale.minMm ? ps.scale.minMm * std::pow(ps.scale.maxMm / ps.scale.minMm, t)
                                                          : ps.scale.maxMm;
        const Rgb8 c = SizeColourScale::colourAt(ps.scale.maxMm > ps.scale.minMm ? t : 1.0);
        stops.push_back(json{{"equivalent_diameter_mm", mm}, {"rgb", {c[0], c[1], c[2]}}});
    }
    json voids = json::array();
    for (const auto& v : ps.voids) {
        const Rgb8 c = ps.scale.colour(v.equivalentDiameterMm);
        voids.push_back(json{{"id", v.id}, {"equivalent_diameter_mm", v.equivalentDiameterMm}, {"rgb", {c[0], c[1], c[2]}}});
    }
    return json{{"schema", "flyover.part_legend/1"},
                {"quantity", "equivalent_diameter_mm"},
                {"scale", "logarithmic from the smallest to the largest listed void: blue, teal, green, yellow, "
                          "orange, red"},
                {"part_rgb", {PART_GREY[0], PART_GREY[1], PART_GREY[2]}},
                {"stops", stops},
                {"voids", voids}};
}

} // namespace

json runPartIngest(PartRun& run, Progress* progress)
{
    IngestParams params;
    params.voxelMm = run.opt.params.ingest.voxelMm;
    // No HU: nothing is "air outside the body". Every voxel stays active.
    params.outsideAirHu = double(std::numeric_limits<float>::lowest());
    params.backgroundHu = 0.0;
    openvdb::FloatGrid::Ptr grid;
    json report = ingestToCtVdb(run, params, ImageReadOptions{}, CT_GRID, progress, grid);
    run.state.hu = grid;
    const auto range = openvdb::tools::minMax(grid->tree());
    report["grey_min"] = range.min();
    report["grey_max"] = range.max();
    return report;
}

json runVoids(PartRun& run, Progress* progress)
{
    const openvdb::FloatGrid::Ptr ct = partGrid(run);
    const VoidParams& vp = run.opt.params.voids;
    auto analysis = std::make_shared<PartAnalysis>(analysePart(*ct, vp, run.opt.ctPath, progress));
    const double voxelMm = ct->voxelSize()[0];

    writeAtomically(run.path("voids.csv"), [&](const std::string& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out << CSV_HEADER << "\n";
        for (const VoidInfo& v : analysis->voids)
            out << v.id << ',' << v.kind << ',' << fixed(v.volumeMm3, 4) << ',' << fixed(v.equivalentDiameterMm, 4) << ','
                << fixed(v.maxExtentMm, 4) << ',' << fixed(v.sphericity, 4) << ',' << fixed(v.centroidLps.x, 4) << ','
                << fixed(v.centroidLps.y, 4) << ',' << fixed(v.centroidLps.z, 4) << ','
                << fixed(v.distanceToSurfaceMm, 4) << "\n";
        out.close();
        if (!out) throw std::runtime_error(tmp + ": write failed");
    });
    json voids = json::array();
    int pores = 0, cracks = 0;
    for (const VoidInfo& v : analysis->voids) {
        voids.push_back(voidJson(v));
        (v.kind == "crack" ? cracks : pores) += 1;
    }
    const json summary{{"schema", "flyover.voids/1"},
                       {"world_frame", WORLD_FRAME},
                       {"input", fs::absolute(run.opt.ctPath).string()},
                       {"voxel_mm", voxelMm},
                       {"threshold", analysis->threshold},
                       {"threshold_source", analysis->thresholdSource},
                       {"min_diameter_voxels", vp.minDiameterVoxels},
                       {"material_volume_mm3", analysis->materialVolumeMm3},
                       {"void_volume_mm3", analysis->voidVolumeMm3},
                       {"porosity_percent", analysis->porosityPercent},
                       {"porosity_definition", "void volume / (material volume + void volume) x 100, all internal "
                                               "voids including the small ones"},
                       {"listed_void_count", analysis->voids.size()},
                       {"small_void_count", analysis->smallVoidCount},
                       {"small_void_volume_mm3", analysis->smallVoidVolumeMm3},
                       {"voids", voids}};
    writeJson(run.path("voids.json"), summary);
    analysis->material->setName("material");
    analysis->outsideAir->setName("outside_air");
    analysis->voidLabels->setName("void_labels");
    writeGrids(run.path("voids.vdb"), {analysis->material, analysis->outsideAir, analysis->voidLabels});
    run.state.part = analysis;
    if (run.opt.log)
        run.opt.log->message("voids: " + std::to_string(analysis->voids.size()) + " listed (" + std::to_string(pores) +
                             " pores, " + std::to_string(cracks) + " cracks), " +
                             std::to_string(analysis->smallVoidCount) + " small; porosity " +
                             fixed(analysis->porosityPercent, 4) + " %");
    return json{{"threshold", analysis->threshold},
                {"threshold_source", analysis->thresholdSource},
                {"listed_voids", analysis->voids.size()},
                {"pores", pores},
                {"cracks", cracks},
                {"small_voids", analysis->smallVoidCount},
                {"porosity_percent", analysis->porosityPercent}};
}

json runPartSurfaces(PartRun& run, Progress* progress)
{
    validatePartSurfaceParams(run.opt.params.surfaces);
    const std::shared_ptr<PartAnalysis> analysis = partAnalysis(run);
    PartField field;
    {
        // Only the grey values within 2.5 voxels of a surface are read (delayed loading).
        const openvdb::FloatGrid::Ptr ct = partGrid(run, true);
        field = makePartField(*ct, *analysis, progress);
    }
    // No later stage reads the grey values: the CT grid (4 B a voxel, the largest thing held)
    // is freed before the mesh is made.
    run.state.hu.reset();
    releaseFreedMemory();
    auto surface = std::make_shared<PartSurface>(
        meshPartField(std::move(field), *analysis, run.opt.params.surfaces, progress));
    writeMesh(run.path("part_surface.ply"), surface->mesh);
    json voids = json::array();
    int64_t voidsWithoutFaces = 0;
    for (std::size_t i = 0; i < surface->voids.size(); ++i) {
        voids.push_back(json{{"id", int(i) + 1}, {"first_face", surface->voids[i].first}, {"faces", surface->voids[i].count}});
        if (surface->voids[i].count == 0) ++voidsWithoutFaces;
    }
    const LumenSurfaceReport& r = surface->report;
    const json checks{{"sound", r.isSound()},
                      {"inward_fraction", r.orientation.inwardFraction()},
                      {"outward_faces", r.orientation.outward},
                      {"degenerate_faces", r.check.degenerateFaces},
                      {"misoriented_components", r.check.misorientedComponents},
                      {"manifold", r.check.isManifold()},
                      {"smoothing_restored_vertices", r.smoothingRestoredVertices}};
    writeJson(run.path("surfaces.json"),
              json{{"schema", "flyover.part_surfaces/1"},
                   {"world_frame", WORLD_FRAME},
                   {"file", "part_surface.ply"},
                   {"orientation", "every face's normal points into the material: seen from outside, OST hides the "
                                   "part's near wall and shows each internal void in place"},
                   {"vertices", surface->mesh.n_vertices()},
                   {"faces", surface->mesh.n_faces()},
                   {"outer", json{{"first_face", surface->outer.first}, {"faces", surface->outer.count}}},
                   {"voids", voids},
                   {"unassigned_faces", surface->unassignedFaces},
                   {"checks", checks}});
    run.state.partSurface = surface;
    if (voidsWithoutFaces > 0 && run.opt.log)
        run.opt.log->message("surfaces: warning: " + std::to_string(voidsWithoutFaces) + " listed voids have no surface");
    return json{{"faces", surface->mesh.n_faces()},
                {"outer_faces", surface->outer.count},
                {"voids_without_faces", voidsWithoutFaces},
                {"unassigned_faces", surface->unassignedFaces},
                {"half_contrast", surface->halfContrast},
                {"checks", checks},
                {"extract_seconds", r.extractSeconds},
                {"smooth_seconds", r.smoothSeconds}};
}

json runPartOverviews(PartRun& run, Progress* progress)
{
    const PartRenderParams& rp = run.opt.params.render;
    const PartScene ps = partScene(run);
    StagedFolder overviews(run.dir, "overviews");
    const RenderOptions ostOptions = partRenderOptions(rp, rp.overviewPx, true);
    const RenderOptions normalOptions = partRenderOptions(rp, rp.overviewPx, false);
    json cameras = json::object(), views = json::object();
    std::vector<int64_t> bestOst(ps.voids.size() + 1, 0), bestOstRays(ps.voids.size() + 1, 0),
        totalNormal(ps.voids.size() + 1, 0), totalNormalRays(ps.voids.size() + 1, 0);
    std::vector<std::vector<std::string>> seenIn(ps.voids.size() + 1);
    RgbImage anterior;
    std::size_t done = 0;
    for (const CanonicalView& view : canonicalViews()) {
        const Camera cam = overviewCamera(ps.scene->boundsMin(), ps.scene->boundsMax(), view.viewDir, view.up, 30.0);
        HitImage ostHits, normalHits;
        std::vector<uint32_t> ostRays, normalRays;
        RgbImage ost = renderFaceColours(*ps.scene, cam, ostOptions, ps.faceColours, &ostHits, &ostRays);
        RgbImage normal = renderFaceColours(*ps.scene, cam, normalOptions, ps.faceColours, &normalHits, &normalRays);
        const auto ostPx = voidPixels(ostHits.primId, ps), normalPx = voidPixels(normalHits.primId, ps);
        const auto ostRy = voidPixels(ostRays, ps), normalRy = voidPixels(normalRays, ps);
        json ostJ = json::object(), normalJ = json::object(), ostRayJ = json::object();
        for (const auto& v : ps.voids) {
            const std::size_t id = std::size_t(v.id);
            if (id >= ostPx.size()) continue;
            ostJ[std::to_string(id)] = ostPx[id];
            normalJ[std::to_string(id)] = normalPx[id];
            ostRayJ[std::to_string(id)] = ostRy[id];
            bestOst[id] = std::max(bestOst[id], ostPx[id]);
            bestOstRays[id] = std::max(bestOstRays[id], ostRy[id]);
            totalNormal[id] += normalPx[id];
            totalNormalRays[id] += normalRy[id];
            if (ostRy[id] > 0) seenIn[id].push_back(view.name);
        }
        views[view.name] = json{{"ost_pixels", ostJ}, {"ost_rays", ostRayJ}, {"normal_pixels", normalJ}};
        cameras[view.name] = cameraJson(cam);
        RgbImage image = comparisonImage(std::move(ost), std::move(normal), ps.scale);
        writePng(overviews.path(std::string(view.name) + ".png"), image);
        if (std::string(view.name) == "anterior") anterior = std::move(image);
        reportProgress(progress, double(++done) / double(canonicalViews().size()), "overviews");
    }
    json perVoid = json::array();
    int64_t unseen = 0, showingInNormal = 0;
    for (const auto& v : ps.voids) {
        const std::size_t id = std::size_t(v.id);
        if (id >= bestOst.size()) continue;
        perVoid.push_back(json{{"id", v.id}, {"ost_views", seenIn[id]}, {"ost_pixels_max", bestOst[id]},
                               {"ost_rays_max", bestOstRays[id]}, {"normal_rays_total", totalNormalRays[id]},
                               {"normal_pixels_total", totalNormal[id]}});
        if (bestOstRays[id] == 0) ++unseen;
        if (totalNormalRays[id] > 0) ++showingInNormal;
    }
    const json render{{"panel_px", rp.overviewPx}, {"supersample", rp.supersample},
                      {"smooth_shading", rp.smoothShading}, {"depth_cue", rp.depthCue}};
    writeJson(overviews.path("cameras.json"), json{{"schema", "flyover.part_overviews/1"},
                                                   {"world_frame", WORLD_FRAME},
                                                   {"layout", "OST | normal (opaque) | size legend"},
                                                   {"render", render},
                                                   {"cameras", cameras}});
    writeJson(overviews.path("visibility.json"),
              json{{"schema", "flyover.part_visibility/1"},
                   {"counted", "ost_pixels: pixels whose centre ray first hits a triangle of the void's surface; "
                               "ost_rays: rays (supersample x supersample per pixel) that do, so a void smaller than "
                               "a pixel still counts; a void is seen in a view (ost_views) when ost_rays > 0, "
                               "normal_rays_total / normal_pixels_total: rays of the normal renders, all views"},
                   {"views", views},
                   {"voids", perVoid},
                   {"voids_unseen_in_ost", unseen},
                   {"voids_seen_in_normal", showingInNormal}});
    writeJson(overviews.path("legend.json"), legendJson(ps));
    writePng(overviews.path("legend.png"), sizeLegendPanel(ps.scale, 96, rp.overviewPx));
    writePng(run.path("overview.png"), anterior);
    overviews.commit();
    if (unseen > 0 && run.opt.log)
        run.opt.log->message("overviews: warning: " + std::to_string(unseen) + " listed voids show in no OST overview");
    return json{{"voids_unseen_in_ost", unseen}, {"voids_seen_in_normal", showingInNormal}};
}

json runTurntable(PartRun& run, Progress* progress)
{
    const PartRenderParams& rp = run.opt.params.render;
    StagedFolder folder(run.dir, "turntable");
    int frames = 0;
    if (rp.video) {
        const std::string ffmpeg = findOnPath("ffmpeg");
        if (ffmpeg.empty())
            throw std::runtime_error("render.video: the 'ffmpeg' program is not on PATH; install it "
                                     "(Debian: apt-get install ffmpeg) or set render.video=false");
        const PartScene ps = partScene(run);
        const Vec3d lo = ps.scene->boundsMin(), hi = ps.scene->boundsMax();
        const Vec3d centre = (lo + hi) * 0.5;
        const double fovDeg = 30.0;
        const double distance = 1.04 * 0.5 * length(hi - lo) / std::sin(0.5 * fovDeg * M_PI / 180.0);
        const RenderOptions ostOptions = partRenderOptions(rp, rp.videoPx, true);
        const RenderOptions normalOptions = partRenderOptions(rp, rp.videoPx, false);
        const RgbImage legend = sizeLegendPanel(ps.scale, 96, rp.videoPx);
        const int width = 2 * rp.videoPx + 4 + 4 + legend.width;
        json poses = json::array();
        writeAtomically(folder.path("turntable.mp4"), [&](const std::string& tmp) {
            FfmpegVideo video(ffmpeg, tmp, folder.path(".ffmpeg.log"), width, rp.videoPx, rp.videoFps);
            for (int k = 0; k < rp.turntableFrames; ++k) {
                // Starts at the anterior view (looking along +y) and turns about the superior axis.
                const double a = 2.0 * M_PI * double(k) / double(rp.turntableFrames);
                const Vec3d viewDir{std::sin(a), std::cos(a), 0.0};
                const Camera cam = lookAt(centre - viewDir * distance, centre, Vec3d{0, 0, 1}, fovDeg);
                RgbImage ost = renderFaceColours(*ps.scene, cam, ostOptions, ps.faceColours);
                RgbImage normal = renderFaceColours(*ps.scene, cam, normalOptions, ps.faceColours);
                video.write(comparisonImage(std::move(ost), std::move(normal), ps.scale));
                poses.push_back(json{{"frame", k}, {"angle_deg", 360.0 * k / rp.turntableFrames}, {"camera", cameraJson(cam)}});
                if (k % 8 == 0) reportProgress(progress, double(k + 1) / double(rp.turntableFrames), "turntable frames");
            }
            video.finish();
        });
        fs::remove(folder.path(".ffmpeg.log"));
        writeJson(folder.path("poses.json"), json{{"schema", "flyover.turntable/1"},
                                                  {"world_frame", WORLD_FRAME},
                                                  {"file", "turntable.mp4"},
                                                  {"codec", "H.264 (libx264 ultrafast, yuv420p, crf 20)"},
                                                  {"fps", rp.videoFps},
                                                  {"layout", "OST | normal (opaque) | size legend"},
                                                  {"axis", "superior (+z) through the part's bounding-box centre"},
                                                  {"frames", poses}});
        frames = rp.turntableFrames;
    }
    folder.commit();
    return json{{"video_frames", frames}};
}

} // namespace flyover
