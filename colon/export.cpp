#include "colon/export.h"

#include "pipeline/artifact_io.h"
#include "surface/mesh_export.h"
#include "volume/error.h"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;

namespace flyover {

void exportMesh(const std::string& studyDir, const std::string& outPath)
{
    const std::string ext = fs::path(outPath).extension().string();
    if (!isMeshFileFormat(ext))
        throw InputError(outPath + ": unsupported mesh format '" + ext + "' (use .ply, .obj, .stl or .off)");
    const TriMesh mesh = readMesh((fs::path(studyDir) / "surface.ply").string());
    // Binary where the format allows (OBJ is text only), OpenMesh's log chatter muted; the
    // temporary file keeps the extension, so the writer picks the same format.
    writeAtomically(outPath, [&](const std::string& tmp) { writeMeshFile(mesh, tmp); });
}

namespace {

bool endsWith(const std::string& s, const std::string& suffix)
{
    return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

nlohmann::json markupsCurve(const Centerline& cl)
{
    using nlohmann::json;
    json points = json::array();
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        const CenterlinePoint& p = cl.points[i];
        points.push_back(json{{"id", std::to_string(i + 1)},
                              {"label", "CL-" + std::to_string(i + 1)},
                              {"description", p.bridged ? "bridged" : ""},
                              {"position", {p.positionMm.x, p.positionMm.y, p.positionMm.z}},
                              {"orientation", {-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0}},
                              {"selected", true},
                              {"locked", true},
                              {"visibility", true},
                              {"positionStatus", "defined"}});
    }
    json curve{{"type", "Curve"},
               {"name", "flyover centerline"},
               {"coordinateSystem", "LPS"},
               {"coordinateUnits", "mm"},
               {"locked", true},
               {"labelFormat", "CL-%d"},
               {"controlPoints", points},
               {"display", {{"pointLabelsVisibility", false}, {"glyphScale", 1.0}, {"lineThickness", 0.2}}}};
    return json{{"@schema", "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
                            "Resources/Schema/markups-schema-v1.0.3.json#"},
                {"markups", json::array({curve})}};
}

std::string vtkPolyline(const Centerline& cl)
{
    std::ostringstream o;
    o.precision(9);
    const std::size_t n = cl.points.size();
    o << "# vtk DataFile Version 3.0\n"
      << "flyover centerline, rectum to cecum, world LPS mm SPACE=LPS\n"
      << "ASCII\nDATASET POLYDATA\nPOINTS " << n << " double\n";
    for (const CenterlinePoint& p : cl.points) o << p.positionMm.x << " " << p.positionMm.y << " " << p.positionMm.z << "\n";
    o << "LINES 1 " << n + 1 << "\n" << n;
    for (std::size_t i = 0; i < n; ++i) o << " " << i;
    o << "\nPOINT_DATA " << n << "\nSCALARS radius_mm double 1\nLOOKUP_TABLE default\n";
    for (const CenterlinePoint& p : cl.points) o << p.radiusMm << "\n";
    o << "SCALARS bridged int 1\nLOOKUP_TABLE default\n";
    for (const CenterlinePoint& p : cl.points) o << (p.bridged ? 1 : 0) << "\n";
    o << "SCALARS arc_mm double 1\nLOOKUP_TABLE default\n";
    for (std::size_t i = 0; i < n; ++i) o << double(i) * cl.stepMm << "\n";
    o << "VECTORS tangent double\n";
    for (const CenterlinePoint& p : cl.points) o << p.tangent.x << " " << p.tangent.y << " " << p.tangent.z << "\n";
    return o.str();
}

} // namespace

void exportCenterline(const std::string& studyDir, const std::string& outPath)
{
    const bool markups = endsWith(outPath, ".mrk.json"), vtk = endsWith(outPath, ".vtk");
    if (!markups && !vtk)
        throw InputError(outPath + ": unsupported centerline format (use .mrk.json for 3D Slicer or .vtk)");
    const std::string source = (fs::path(studyDir) / "centerline.json").string();
    if (!fs::exists(source)) throw InputError(studyDir + ": no centerline.json (run the centerline stage first)");
    const Centerline cl = centerlineFromJson(readJson(source), source);
    if (cl.points.empty()) throw InputError(source + ": the centerline has no points");
    const std::string text = markups ? markupsCurve(cl).dump() + "\n" : vtkPolyline(cl);
    writeAtomically(outPath, [&](const std::string& tmp) {
        std::ofstream f(tmp, std::ios::binary);
        f << text;
        f.close();
        if (!f) throw InputError(outPath + ": cannot write");
    });
}

} // namespace flyover
