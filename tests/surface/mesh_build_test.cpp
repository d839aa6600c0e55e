#include "surface/mesh_build.h"

#include "surface/openmesh_log.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace flyover {
namespace {

using Faces = std::vector<std::array<int, 3>>;

TriMesh meshWithVertices(int n)
{
    TriMesh mesh;
    mesh.resize(std::size_t(n), 0, 0);
    for (int i = 0; i < n; ++i) mesh.set_point(TriMesh::VertexHandle(i), TriMesh::Point(float(i), 0.f, 0.f));
    return mesh;
}

/// OpenMesh's own incremental build, the reference.
TriMesh buildWithAddFace(int n, const Faces& faces, int64_t* refused)
{
    TriMesh mesh = meshWithVertices(n);
    const ScopedOpenMeshMute muted(ScopedOpenMeshMute::ERR);
    *refused = 0;
    for (const auto& f : faces) {
        const TriMesh::VertexHandle a(f[0]), b(f[1]), c(f[2]);
        if (a == b || b == c || a == c || !mesh.add_face(a, b, c).is_valid()) ++*refused;
    }
    return mesh;
}

/// Every handle of both meshes, element by element; the first difference, or "".
std::string firstDifference(const TriMesh& want, const TriMesh& got)
{
    std::ostringstream o;
    if (want.n_vertices() != got.n_vertices() || want.n_edges() != got.n_edges() ||
        want.n_faces() != got.n_faces()) {
        o << "sizes V/E/F expected " << want.n_vertices() << "/" << want.n_edges() << "/"
          << want.n_faces() << ", got " << got.n_vertices() << "/" << got.n_edges() << "/"
          << got.n_faces();
        return o.str();
    }
    for (std::size_t i = 0; i < want.n_vertices(); ++i) {
        const TriMesh::VertexHandle v{int(i)};
        if (want.halfedge_handle(v) != got.halfedge_handle(v)) {
            o << "vertex " << i << " halfedge: expected " << want.halfedge_handle(v).idx() << ", got "
              << got.halfedge_handle(v).idx();
            return o.str();
        }
    }
    for (std::size_t i = 0; i < want.n_halfedges(); ++i) {
        const TriMesh::HalfedgeHandle h{int(i)};
        const int w[4] = {want.to_vertex_handle(h).idx(), want.face_handle(h).idx(),
                          want.next_halfedge_handle(h).idx(), want.prev_halfedge_handle(h).idx()};
        const int g[4] = {got.to_vertex_handle(h).idx(), got.face_handle(h).idx(),
                          got.next_halfedge_handle(h).idx(), got.prev_halfedge_handle(h).idx()};
        for (int k = 0; k < 4; ++k)
            if (w[k] != g[k]) {
                static const char* what[4] = {"to vertex", "face", "next", "prev"};
                o << "halfedge " << i << " " << what[k] << ": expected " << w[k] << ", got " << g[k];
                return o.str();
            }
    }
    for (std::size_t i = 0; i < want.n_faces(); ++i) {
        const TriMesh::FaceHandle f{int(i)};
        if (want.halfedge_handle(f) != got.halfedge_handle(f)) {
            o << "face " << i << " halfedge: expected " << want.halfedge_handle(f).idx() << ", got "
              << got.halfedge_handle(f).idx();
            return o.str();
        }
    }
    return "";
}

void expectSameAsAddFace(int n, const Faces& faces, const std::string& what)
{
    int64_t refusedWant = 0;
    const TriMesh want = buildWithAddFace(n, faces, &refusedWant);
    TriMesh got = meshWithVertices(n);
    const int64_t refusedGot = addFacesLikeOpenMesh(got, faces);
    EXPECT_EQ(refusedWant, refusedGot) << what << ": faces refused";
    EXPECT_EQ("", firstDifference(want, got)) << what;
}

/// A closed sphere from volumeToMesh (quads split), its vertices used in order.
Faces sphereFaces(int* nVertices)
{
    const auto sdf = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(10.f, openvdb::Vec3f(0.f), 0.5f);
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> tris;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*sdf, points, tris, quads, 0.0, 0.0);
    Faces faces;
    for (const auto& t : tris) faces.push_back({int(t[0]), int(t[1]), int(t[2])});
    for (const auto& q : quads) {
        faces.push_back({int(q[0]), int(q[1]), int(q[2])});
        faces.push_back({int(q[0]), int(q[2]), int(q[3])});
    }
    *nVertices = int(points.size());
    return faces;
}

TEST(AddFacesLikeOpenMesh, ClosedSphereInVolumeToMeshOrderGivesAddFacesHandles)
{
    int n = 0;
    const Faces faces = sphereFaces(&n);
    ASSERT_GT(faces.size(), 1000u);
    expectSameAsAddFace(n, faces, "sphere, volumeToMesh order");
}

TEST(AddFacesLikeOpenMesh, ShuffledFacesRelinkPatchesLikeAddFace)
{
    // In random order the faces meet as separate fans around a vertex: add_face's patch
    // re-linking, its "complex vertex" refusals and its outgoing-halfedge adjustments.
    int n = 0;
    Faces faces = sphereFaces(&n);
    for (const unsigned seed : {1u, 2u, 3u}) {
        std::mt19937 rng(seed);
        std::shuffle(faces.begin(), faces.end(), rng);
        expectSameAsAddFace(n, faces, "sphere shuffled, seed " + std::to_string(seed));
    }
}

TEST(AddFacesLikeOpenMesh, RandomSoupsRefuseTheFacesAddFaceRefuses)
{
    // Few vertices, many faces: repeated vertices, complex edges (a third face on an edge,
    // an edge used twice in one direction), non-manifold vertices.
    for (const unsigned seed : {11u, 12u, 13u, 14u, 15u}) {
        std::mt19937 rng(seed);
        const int n = 30;
        std::uniform_int_distribution<int> pick(0, n - 1);
        Faces faces(400);
        for (auto& f : faces) f = {pick(rng), pick(rng), pick(rng)};
        expectSameAsAddFace(n, faces, "random soup, seed " + std::to_string(seed));
    }
}

TEST(AddFacesLikeOpenMesh, RefusesIndexOutsideTheVerticesOrAMeshWithFaces)
{
    TriMesh mesh = meshWithVertices(3);
    EXPECT_THROW(addFacesLikeOpenMesh(mesh, Faces{{0, 1, 3}}), ParameterError);
    EXPECT_EQ(0, addFacesLikeOpenMesh(mesh, Faces{{0, 1, 2}}));
    EXPECT_THROW(addFacesLikeOpenMesh(mesh, Faces{{0, 2, 1}}), ParameterError);
}

} // namespace
} // namespace flyover
