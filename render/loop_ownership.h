/// @file loop_ownership.h
/// @brief Which part of the path each wall triangle belongs to, through the lumen: the arc
///        (mm along the centerline) of a path point that sees the triangle's front (lumen)
///        side with nothing in between. Touching loops are near in space and far along the
///        colon; a wall is reached from inside its own loop, so the nearest path point in
///        space is not the owner when it lies in the loop next door (behind its own wall).
///        Loop-local OST (RenderOptions::loop) passes through the walls of other loops.
///
/// Rule, per triangle (centroid c, front normal n): the path points, one per 10 mm stretch of
/// arc, are tried nearest stretch first (up to 8 stretches within 60 mm of the nearest); the
/// first point p with dot(c - p, n) < 0 (p is on the front side) and no face between p and c
/// owns it. Triangles no point sees (the hidden side of a fold, a haustral pocket) take the
/// owner of a triangle next to them on the mesh, breadth-first. A triangle left without an
/// owner (a piece of surface no path point sees) gets NaN: it is never passed through.
#pragma once

#include "render/ray_scene.h"
#include "volume/centerline_types.h"

#include <cstddef>
#include <string>
#include <vector>

namespace flyover {

struct TriangleOwners {
    std::vector<float> arcMm;        ///< per scene triangle: the owner's arc (mm), NaN when none
    std::size_t bySight = 0;         ///< triangles a path point sees
    std::size_t byNeighbour = 0;     ///< triangles that took a neighbour's owner
    std::size_t unowned = 0;         ///< triangles left NaN
    double seconds = 0;
};

/// @throw InputError for an empty centerline
TriangleOwners triangleOwners(const RayScene& scene, const Centerline& centerline);

/// The owners as the frames step keeps them beside its pairs (frames/owners.f32): one
/// little-endian float32 per triangle of surface.ply, NaN for none; the viewer reads them
/// instead of computing them again.
inline constexpr const char* OWNERS_FILE = "owners.f32";
/// Writes atomically (a temporary file renamed). @throw std::runtime_error naming the file
void writeOwners(const std::string& path, const std::vector<float>& arcMm);
/// @return false when the file is absent or does not hold exactly `triangles` owners (stale:
/// another surface's); @throw InputError when it holds a value that is neither finite nor NaN
bool readOwners(const std::string& path, std::size_t triangles, std::vector<float>& arcMm);

} // namespace flyover
