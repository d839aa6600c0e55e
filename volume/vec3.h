/// @file vec3.h
/// @brief A small double-precision 3-vector used across modules for world positions (mm)
///        and directions. Deliberately free of OpenVDB so that render/ does not need it.
#pragma once

#include <algorithm>
#include <cmath>

namespace flyover {

/// pi, for every module (one definition, so files can share a unity-build batch).
inline constexpr double PI = 3.14159265358979323846;

struct Vec3d {
    double x = 0.0, y = 0.0, z = 0.0;

    constexpr Vec3d() = default;
    constexpr Vec3d(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}

    constexpr double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    double& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }

    constexpr Vec3d operator+(const Vec3d& o) const { return {x + o.x, y + o.y, z + o.z}; }
    constexpr Vec3d operator-(const Vec3d& o) const { return {x - o.x, y - o.y, z - o.z}; }
    constexpr Vec3d operator-() const { return {-x, -y, -z}; }
    constexpr Vec3d operator*(double s) const { return {x * s, y * s, z * s}; }
    constexpr Vec3d operator/(double s) const { return {x / s, y / s, z / s}; }
    Vec3d& operator+=(const Vec3d& o) { x += o.x; y += o.y; z += o.z; return *this; }
    Vec3d& operator-=(const Vec3d& o) { x -= o.x; y -= o.y; z -= o.z; return *this; }
    Vec3d& operator*=(double s) { x *= s; y *= s; z *= s; return *this; }
    constexpr bool operator==(const Vec3d& o) const { return x == o.x && y == o.y && z == o.z; }
    constexpr bool operator!=(const Vec3d& o) const { return !(*this == o); }
};

constexpr Vec3d operator*(double s, const Vec3d& v) { return v * s; }
constexpr double dot(const Vec3d& a, const Vec3d& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
constexpr Vec3d cross(const Vec3d& a, const Vec3d& b)
{
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(const Vec3d& v) { return std::sqrt(dot(v, v)); }
inline double distance(const Vec3d& a, const Vec3d& b) { return length(a - b); }
/// Distance from `p` to the segment a-b (to a when the segment has no length).
inline double distanceToSegment(const Vec3d& p, const Vec3d& a, const Vec3d& b)
{
    const Vec3d ab = b - a;
    const double len2 = dot(ab, ab);
    const double t = len2 > 0 ? std::clamp(dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
    return distance(p, a + ab * t);
}
/// @return v / |v|, or the zero vector when |v| is zero.
inline Vec3d normalize(const Vec3d& v)
{
    const double n = length(v);
    return n > 0.0 ? v / n : Vec3d{};
}

} // namespace flyover
