/// @file export.h
/// @brief `flyover export`: a study's results in formats other tools load.
#pragma once

#include <string>

namespace flyover {

/// Writes the study's lumen surface (surface.ply) as .ply, .obj, .stl or .off (by extension)
/// through OpenMesh's writers, binary where the format allows.
/// @throw InputError naming the study or the output file.
void exportMesh(const std::string& studyDir, const std::string& outPath);

/// Writes the study's lumen as a uint8 mask (1 inside) on the original scan's voxel grid and
/// geometry (the ingest report's input lattice; for a study made from a mask alone, the
/// mask's), so that it overlays the CT in other tools; the format follows the extension
/// (.nii.gz, .nii, .nrrd, .mha). A voxel is inside when the lumen level set is negative at
/// its centre.
/// @throw InputError naming the study or the output file.
void exportLumen(const std::string& studyDir, const std::string& outPath);

/// Writes the study's centerline (centerline.json) for radiology tools, by extension:
///   .mrk.json  3D Slicer markups curve (schema v1.0.3, coordinateSystem LPS, mm): one control
///              point per centerline point, rectum first; bridged points carry the description
///              "bridged" (Slicer shows it in the control point table).
///   .vtk       legacy VTK polydata (ASCII): one polyline, with point data radius_mm, bridged
///              (0/1), arc_mm and tangent; LPS mm, stated in the header line ("SPACE=LPS", as
///              Slicer writes and reads it).
/// @throw InputError naming the study or the output file.
void exportCenterline(const std::string& studyDir, const std::string& outPath);

} // namespace flyover
