/// @file export.h
/// @brief `flyover export`: a study's results in formats other tools load.
#pragma once

#include <string>

namespace flyover {

/// Writes the study's lumen surface (surface.ply) as .ply, .obj, .stl or .off (by extension)
/// through OpenMesh's writers, binary where the format allows.
/// @throw InputError naming the study or the output file.
void exportMesh(const std::string& studyDir, const std::string& outPath);

} // namespace flyover
