#include "tests/shapes/surface_shapes.h"

#include <openvdb/tools/SignedFloodFill.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace flyover::test {

namespace {

class OpenVdbEnvironment : public ::testing::Environment {
public:
    void SetUp() override { openvdb::initialize(); }
};
const auto* const ENV = ::testing::AddGlobalTestEnvironment(new OpenVdbEnvironment);

openvdb::FloatGrid::Ptr sample(const DistanceFn& distanceMm, const openvdb::Vec3d& loMm, const openvdb::Vec3d& hiMm,
                               double voxelMm, double halfWidthVoxels, bool staircase)
{
    const float background = float(halfWidthVoxels * voxelMm);
    auto grid = openvdb::FloatGrid::create(background);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelMm));
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    auto acc = grid->getAccessor();
    const openvdb::Coord from(openvdb::Coord::floor(loMm / voxelMm));
    const openvdb::Coord to(openvdb::Coord::ceil(hiMm / voxelMm));
    for (int i = from.x(); i <= to.x(); ++i)
        for (int j = from.y(); j <= to.y(); ++j)
            for (int k = from.z(); k <= to.z(); ++k) {
                const openvdb::Vec3d p = openvdb::Vec3d(i, j, k) * voxelMm;
                const double d = distanceMm(p);
                if (!(std::fabs(d) < background)) continue;
                const double value = staircase ? (d < 0 ? -0.5 : 0.5) * voxelMm : d;
                acc.setValue(openvdb::Coord(i, j, k), float(value));
            }
    openvdb::tools::signedFloodFill(grid->tree());
    return grid;
}

} // namespace

openvdb::FloatGrid::Ptr sampleSdf(const DistanceFn& distanceMm, const openvdb::Vec3d& loMm, const openvdb::Vec3d& hiMm,
                                  double voxelMm, double halfWidthVoxels)
{
    return sample(distanceMm, loMm, hiMm, voxelMm, halfWidthVoxels, false);
}

openvdb::FloatGrid::Ptr sampleStaircaseSdf(const DistanceFn& distanceMm, const openvdb::Vec3d& loMm,
                                           const openvdb::Vec3d& hiMm, double voxelMm)
{
    return sample(distanceMm, loMm, hiMm, voxelMm, 3.0, true);
}

double firstHitMm(const TriMesh& mesh, const OpenMesh::Vec3d& o, const OpenMesh::Vec3d& d, double tMaxMm)
{
    double best = tMaxMm;
    for (const auto f : mesh.faces()) {
        OpenMesh::Vec3d v[3];
        int k = 0;
        for (const auto vh : mesh.fv_range(f)) v[k++] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(vh));
        // Moller-Trumbore, both sides.
        const OpenMesh::Vec3d e1 = v[1] - v[0], e2 = v[2] - v[0];
        const OpenMesh::Vec3d pv = OpenMesh::cross(d, e2);
        const double det = OpenMesh::dot(e1, pv);
        if (!(std::fabs(det) > 1e-14)) continue;
        const OpenMesh::Vec3d tv = o - v[0];
        const double u = OpenMesh::dot(tv, pv) / det;
        if (u < 0 || u > 1) continue;
        const OpenMesh::Vec3d qv = OpenMesh::cross(tv, e1);
        const double w = OpenMesh::dot(d, qv) / det;
        if (w < 0 || u + w > 1) continue;
        const double t = OpenMesh::dot(e2, qv) / det;
        if (t > 0 && t < best) best = t;
    }
    return best;
}

AngleError normalAngleError(const TriMesh& mesh,
                            const std::function<OpenMesh::Vec3d(const OpenMesh::Vec3d& pMm)>& inwardNormal)
{
    AngleError e;
    double sum = 0;
    for (const auto f : mesh.faces()) {
        OpenMesh::Vec3d v[3];
        int k = 0;
        for (const auto vh : mesh.fv_range(f)) v[k++] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(vh));
        const OpenMesh::Vec3d n = OpenMesh::cross(v[1] - v[0], v[2] - v[0]).normalized();
        const OpenMesh::Vec3d ref = inwardNormal((v[0] + v[1] + v[2]) / 3.0).normalized();
        const double angle = std::atan2(OpenMesh::cross(n, ref).norm(), OpenMesh::dot(n, ref)) * 180.0 / PI;
        sum += angle;
        e.maxDeg = std::max(e.maxDeg, angle);
    }
    e.meanDeg = mesh.n_faces() > 0 ? sum / double(mesh.n_faces()) : 0.0;
    return e;
}

double polypHeightMm(const TriMesh& mesh, const PolypSite& q)
{
    const double reach = 3.0 * q.tubeRadiusMm;
    const double tip = firstHitMm(mesh, q.centreMm, -q.outwardDir, reach);
    const double apex = (q.centreMm - q.axisMm).norm() - tip;
    const double theta = 2.0 * std::asin(std::min(0.99, (q.radiusMm + 2.0) / (2.0 * q.tubeRadiusMm)));
    const OpenMesh::Vec3d side = OpenMesh::cross(q.tangent, q.outwardDir).normalized();
    double wall = 0;
    for (const double s : {-1.5, -1.0, 1.0, 1.5}) {
        const double a = s * theta;
        const double t = firstHitMm(mesh, q.axisMm, q.outwardDir * std::cos(a) + side * std::sin(a), reach);
        if (t < reach) wall = std::max(wall, t);
    }
    return wall - apex;
}

TriMesh flipped(const TriMesh& mesh)
{
    TriMesh out;
    for (const auto v : mesh.vertices()) out.add_vertex(mesh.point(v));
    for (const auto f : mesh.faces()) {
        std::vector<TriMesh::VertexHandle> vs;
        for (const auto v : mesh.fv_range(f)) vs.push_back(TriMesh::VertexHandle(v.idx()));
        out.add_face(vs[0], vs[2], vs[1]);
    }
    return out;
}

} // namespace flyover::test
