// The OpenMesh decimater headers live in this translation unit only (style.md).
#include "surface/decimate_mesh.h"

#include "volume/error.h"

#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModHausdorffT.hh>
#include <OpenMesh/Tools/Decimater/ModNormalFlippingT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>

#include <array>
#include <sstream>
#include <string>
#include <utility>

namespace flyover {

namespace {

/// Binary decimater module: refuses a collapse when a triangle around the surviving vertex,
/// at its new position, fails a caller's test (the faces the collapse removes are skipped).
template <class MeshT>
class ModTriangleTestT : public OpenMesh::Decimater::ModBaseT<MeshT> {
public:
    DECIMATING_MODULE(ModTriangleTestT, MeshT, TriangleTest);
    using Test = std::function<bool(const OpenMesh::Vec3d&, const OpenMesh::Vec3d&, const OpenMesh::Vec3d&)>;

    explicit ModTriangleTestT(MeshT& mesh) : Base(mesh, true) {}

    void setTest(Test test) { mTest = std::move(test); }

    float collapse_priority(const CollapseInfo& ci) override
    {
        MeshT& mesh = Base::mesh();
        for (const auto f : mesh.vf_range(ci.v0)) {
            if (f == ci.fl || f == ci.fr) continue;
            std::array<OpenMesh::Vec3d, 3> p;
            int k = 0;
            for (const auto v : mesh.fv_range(f))
                p[std::size_t(k++)] = OpenMesh::vector_cast<OpenMesh::Vec3d>(v == ci.v0 ? ci.p1 : mesh.point(v));
            if (!mTest(p[0], p[1], p[2])) return float(Base::ILLEGAL_COLLAPSE);
        }
        return float(Base::LEGAL_COLLAPSE);
    }

private:
    Test mTest;
};

} // namespace

void decimateMesh(TriMesh& mesh, const DecimateParams& params, DecimateReport* report, Progress* progress)
{
    auto fail = [](const std::string& name, double value, const char* expected) {
        std::ostringstream msg;
        msg << "DecimateParams." << name << ": expected " << expected << ", got " << value;
        throw ParameterError(msg.str());
    };
    if (!(params.targetFaces >= 0)) fail("targetFaces", double(params.targetFaces), ">= 0");
    if (!(params.maxErrorMm >= 0.0)) fail("maxErrorMm", params.maxErrorMm, ">= 0");
    if (!(params.maxNormalDeviationDeg > 0.0 && params.maxNormalDeviationDeg <= 180.0))
        fail("maxNormalDeviationDeg", params.maxNormalDeviationDeg, "a value in (0, 180]");

    DecimateReport rep;
    rep.facesBefore = rep.facesAfter = int64_t(mesh.n_faces());
    const bool hasBudget = params.targetFaces > 0 && params.targetFaces < rep.facesBefore;
    if (hasBudget || params.maxErrorMm > 0.0) {
        reportProgress(progress, 0.0, "decimation");
        mesh.request_vertex_status();
        mesh.request_edge_status();
        mesh.request_face_status();
        // The flip guard compares against stored face normals; computing them here avoids
        // OpenMesh's "Mesh has no face normals" message.
        mesh.request_face_normals();
        mesh.update_face_normals();
        {
            using Decimater = OpenMesh::Decimater::DecimaterT<TriMesh>;
            Decimater decimater(mesh);
            OpenMesh::Decimater::ModQuadricT<TriMesh>::Handle quadric;
            OpenMesh::Decimater::ModNormalFlippingT<TriMesh>::Handle flip;
            OpenMesh::Decimater::ModHausdorffT<TriMesh>::Handle hausdorff;
            ModTriangleTestT<TriMesh>::Handle triangleTest;
            decimater.add(quadric);  // priority only: no quadric bound (its unit is mm^4)
            decimater.module(quadric).unset_max_err();
            decimater.add(flip);
            decimater.module(flip).set_max_normal_deviation(params.maxNormalDeviationDeg);
            if (params.maxErrorMm > 0.0) {
                decimater.add(hausdorff);
                decimater.module(hausdorff).set_tolerance(float(params.maxErrorMm));
            }
            if (params.acceptTriangle) {
                decimater.add(triangleTest);
                decimater.module(triangleTest).setTest(params.acceptTriangle);
            }
            if (!decimater.initialize())
                throw std::logic_error("decimateMesh: OpenMesh decimater failed to initialise");
            const std::size_t target = hasBudget ? std::size_t(params.targetFaces) : 0;
            rep.collapses = int64_t(decimater.decimate_to_faces(0, target));
        }
        mesh.garbage_collection();
        mesh.release_face_normals();
        mesh.release_face_status();
        mesh.release_edge_status();
        mesh.release_vertex_status();
        rep.facesAfter = int64_t(mesh.n_faces());
        rep.reachedTarget = hasBudget && rep.facesAfter <= params.targetFaces;
        reportProgress(progress, 1.0, "decimation done");
    }
    if (report) *report = rep;
}

} // namespace flyover
