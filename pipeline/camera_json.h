/// @file camera_json.h
/// @brief A camera as the poses files of the render steps write it (LPS mm).
#pragma once

#include "render/camera.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>

namespace flyover {

inline nlohmann::json cameraJson(const Camera& c)
{
    auto v = [](const Vec3d& x) { return nlohmann::json::array({x.x, x.y, x.z}); };
    return nlohmann::json{{"position_mm", v(c.position)}, {"forward", v(c.forward)},
                          {"up", v(c.up)},                {"right", v(c.right)},
                          {"fov_deg", c.fovDeg},          {"near_mm", c.nearMm}};
}

} // namespace flyover
