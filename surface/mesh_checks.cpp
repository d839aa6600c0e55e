#include "surface/mesh_checks.h"
#include "volume/vec3.h"

#include "surface/ray_winding.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <numeric>
#include <optional>
#include <vector>

namespace flyover {

namespace {

using Point3d = OpenMesh::Vec3d;

/// Below this many (probes x faces) a container's probes get the solid-angle sum directly.
constexpr std::size_t RAY_NESTING_MIN_WORK = std::size_t(1) << 22;

Point3d pointOf(const TriMesh& mesh, TriMesh::VertexHandle v)
{
    return OpenMesh::vector_cast<Point3d>(mesh.point(v));
}

/// A triangle as three points, for the volume and winding sums (mesh faces and loop caps).
using Triangle = std::array<Point3d, 3>;

struct Box {
    Point3d lo{std::numeric_limits<double>::max()};
    Point3d hi{-std::numeric_limits<double>::max()};
    void add(const Point3d& p)
    {
        lo.minimize(p);
        hi.maximize(p);
    }
    bool contains(const Box& b) const
    {
        for (int a = 0; a < 3; ++a)
            if (b.lo[a] < lo[a] || b.hi[a] > hi[a]) return false;
        return true;
    }
};

/// Everything known about one component while measuring it.
struct ComponentWork {
    MeshComponent info;
    std::vector<Triangle> caps;  ///< fans closing its boundary loops
    Box box;
    Point3d probe{0.0};            ///< a vertex of the component, for the nesting test
};

/// Solid angle (steradians, signed by winding) of triangle t seen from p
/// (Van Oosterom and Strackee's formula).
double solidAngle(const Triangle& t, const Point3d& p)
{
    const Point3d a = t[0] - p, b = t[1] - p, c = t[2] - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double numerator = OpenMesh::dot(a, OpenMesh::cross(b, c));
    const double denominator = la * lb * lc + OpenMesh::dot(a, b) * lc + OpenMesh::dot(a, c) * lb +
                               OpenMesh::dot(b, c) * la;
    return 2.0 * std::atan2(numerator, denominator);
}

/// Generalised winding number of p with respect to the faces of one component (and its caps).
double windingNumber(const TriMesh& mesh, const std::vector<TriMesh::FaceHandle>& faces,
                     const std::vector<Triangle>& caps, const Point3d& p)
{
    const double sum = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, faces.size(), 4096), 0.0,
        [&](const tbb::blocked_range<std::size_t>& r, double acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                Triangle t;
                int k = 0;
                for (const auto v : mesh.fv_range(faces[i])) t[std::size_t(k++)] = pointOf(mesh, v);
                acc += solidAngle(t, p);
            }
            return acc;
        },
        [](double a, double b) { return a + b; });
    double capSum = 0.0;
    for (const Triangle& t : caps) capSum += solidAngle(t, p);
    return (sum + capSum) / (4.0 * PI);
}

/// det(p0 - ref, p1 - ref, p2 - ref): six times the signed volume of the tetrahedron.
double tripleProduct(const Triangle& t, const Point3d& ref)
{
    return OpenMesh::dot(t[0] - ref, OpenMesh::cross(t[1] - ref, t[2] - ref));
}

bool isDegenerate(const Triangle& t)
{
    const double twiceArea = OpenMesh::cross(t[1] - t[0], t[2] - t[0]).norm();
    const double longest2 =
        std::max({(t[1] - t[0]).sqrnorm(), (t[2] - t[1]).sqrnorm(), (t[0] - t[2]).sqrnorm()});
    return isDegenerateTriangle(twiceArea, longest2);
}

} // namespace

bool isDegenerateFace(const TriMesh& mesh, TriMesh::FaceHandle face)
{
    Triangle t;
    int k = 0;
    for (const auto v : mesh.fv_range(face)) t[std::size_t(k++)] = pointOf(mesh, v);
    return isDegenerate(t);
}

namespace {

/// meanDihedralAngleDeg with the vertex positions `pointAt(v)` (a Point3d) instead of the mesh's.
template<typename PointAt>
double meanDihedralAngleDegAt(const TriMesh& mesh, const PointAt& pointAt)
{
    struct Sum {
        double angle = 0;
        int64_t count = 0;
    };
    auto unitNormal = [&](TriMesh::FaceHandle f, Point3d& n) {
        Triangle t;
        int k = 0;
        for (const auto v : mesh.fv_range(f)) t[std::size_t(k++)] = pointAt(v);
        n = OpenMesh::cross(t[1] - t[0], t[2] - t[0]);
        if (isDegenerate(t)) return false;
        n /= n.norm();
        return true;
    };
    const Sum s = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, mesh.n_edges(), 4096), Sum{},
        [&](const tbb::blocked_range<std::size_t>& r, Sum acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                const TriMesh::EdgeHandle e{int(i)};
                const TriMesh::FaceHandle f0 = mesh.face_handle(mesh.halfedge_handle(e, 0));
                const TriMesh::FaceHandle f1 = mesh.face_handle(mesh.halfedge_handle(e, 1));
                Point3d n0, n1;
                if (!f0.is_valid() || !f1.is_valid() || !unitNormal(f0, n0) || !unitNormal(f1, n1))
                    continue;
                // atan2 of |cross| and dot stays accurate for nearly parallel normals.
                acc.angle += std::atan2(OpenMesh::cross(n0, n1).norm(), OpenMesh::dot(n0, n1));
                ++acc.count;
            }
            return acc;
        },
        [](Sum a, const Sum& b) {
            a.angle += b.angle;
            a.count += b.count;
            return a;
        });
    return s.count > 0 ? s.angle / double(s.count) * 180.0 / PI : 0.0;
}

} // namespace

double meanDihedralAngleDeg(const TriMesh& mesh)
{
    return meanDihedralAngleDegAt(mesh, [&](TriMesh::VertexHandle v) { return pointOf(mesh, v); });
}

double meanDihedralAngleDeg(const TriMesh& mesh, const std::vector<TriMesh::Point>& points)
{
    return meanDihedralAngleDegAt(mesh, [&](TriMesh::VertexHandle v) {
        return OpenMesh::vector_cast<Point3d>(points[std::size_t(v.idx())]);
    });
}

namespace {

/// Edge-connected face components (depth-first over face neighbours): `faceComponent` receives
/// each face's component; returns each component's faces in the order reached.
std::vector<std::vector<TriMesh::FaceHandle>> faceComponents(const TriMesh& mesh, std::vector<int>& faceComponent)
{
    constexpr int NONE = -1;
    faceComponent.assign(mesh.n_faces(), NONE);
    std::vector<std::vector<TriMesh::FaceHandle>> componentFaces;
    std::vector<TriMesh::FaceHandle> stack;
    for (const auto f : mesh.faces()) {
        if (faceComponent[std::size_t(f.idx())] != NONE) continue;
        const int c = int(componentFaces.size());
        componentFaces.emplace_back();
        faceComponent[std::size_t(f.idx())] = c;
        stack.push_back(f);
        while (!stack.empty()) {
            const TriMesh::FaceHandle g = stack.back();
            stack.pop_back();
            componentFaces[std::size_t(c)].push_back(g);
            for (auto ff = mesh.cff_iter(g); ff.is_valid(); ++ff) {
                int& mark = faceComponent[std::size_t(ff->idx())];
                if (mark == NONE) {
                    mark = c;
                    stack.push_back(*ff);
                }
            }
        }
    }
    return componentFaces;
}

/// Counts the vertices and edges, each in the component of any incident face (with its box and
/// probe), and the mesh's non-manifold and isolated vertices and boundary edges.
template<typename PointAt>
void countVerticesAndEdges(const TriMesh& mesh, const PointAt& pointAt, const std::vector<int>& faceComponent,
                           std::vector<ComponentWork>& work, MeshCheck& check)
{
    for (const auto v : mesh.vertices()) {
        if (!mesh.is_manifold(v)) ++check.nonManifoldVertices;
        TriMesh::FaceHandle f;
        for (const auto vf : mesh.vf_range(v)) {
            f = vf;
            break;
        }
        if (!f.is_valid()) {
            ++check.isolatedVertices;
            continue;
        }
        ComponentWork& w = work[std::size_t(faceComponent[std::size_t(f.idx())])];
        if (w.info.vertices == 0) w.probe = pointAt(v);
        ++w.info.vertices;
        w.box.add(pointAt(v));
    }
    for (const auto e : mesh.edges()) {
        TriMesh::FaceHandle f = mesh.face_handle(e.h0());
        if (!f.is_valid()) f = mesh.face_handle(e.h1());
        if (!f.is_valid()) continue;  // a dangling edge: no component
        ++work[std::size_t(faceComponent[std::size_t(f.idx())])].info.edges;
        if (e.is_boundary()) ++check.boundaryEdges;
    }
}

/// Boundary loops: cycles of boundary halfedges. Each gets a cap, a fan to its centroid,
/// wound against the adjacent faces (they use the edge b->a, the cap uses a->b).
template<typename PointAt>
void capBoundaryLoops(const TriMesh& mesh, const PointAt& pointAt, const std::vector<int>& faceComponent,
                      std::vector<ComponentWork>& work)
{
    std::vector<char> seen(mesh.n_halfedges(), 0);
    for (const auto h : mesh.halfedges()) {
        if (!h.is_boundary() || seen[std::size_t(h.idx())]) continue;
        const TriMesh::FaceHandle f = mesh.face_handle(h.opp());
        if (!f.is_valid()) {  // dangling edge, no face on either side
            seen[std::size_t(h.idx())] = 1;
            continue;
        }
        ComponentWork& w = work[std::size_t(faceComponent[std::size_t(f.idx())])];
        std::vector<TriMesh::HalfedgeHandle> loop;
        // The walk closes for any halfedge structure, but guard it against corrupted
        // connectivity rather than loop forever.
        for (TriMesh::HalfedgeHandle g = h; !seen[std::size_t(g.idx())] && loop.size() <= mesh.n_halfedges();
             g = mesh.next_halfedge_handle(g)) {
            seen[std::size_t(g.idx())] = 1;
            loop.push_back(g);
        }
        Point3d centroid(0.0);
        for (const auto g : loop) centroid += pointAt(mesh.from_vertex_handle(g));
        centroid /= double(loop.size());
        for (const auto g : loop)
            w.caps.push_back({pointAt(mesh.from_vertex_handle(g)),
                              pointAt(mesh.to_vertex_handle(g)), centroid});
        ++w.info.boundaryLoops;
    }
}

/// Area, degenerate faces (added to check.degenerateFaces), capped volume and genus of one
/// component with faces `faces`.
template<typename PointAt>
void measureComponent(const TriMesh& mesh, const PointAt& pointAt, const std::vector<TriMesh::FaceHandle>& faces,
                      ComponentWork& w, MeshCheck& check)
{
    w.info.faces = int64_t(faces.size());
    // A reference point near the component keeps float cancellation small.
    const Point3d ref = 0.5 * (w.box.lo + w.box.hi);
    struct Sums {
        double area = 0, volume6 = 0;
        int64_t degenerate = 0;
    };
    const Sums s = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, faces.size(), 4096), Sums{},
        [&](const tbb::blocked_range<std::size_t>& r, Sums acc) {
            for (std::size_t i = r.begin(); i != r.end(); ++i) {
                Triangle t;
                int k = 0;
                for (const auto v : mesh.fv_range(faces[i])) t[std::size_t(k++)] = pointAt(v);
                acc.area += 0.5 * OpenMesh::cross(t[1] - t[0], t[2] - t[0]).norm();
                acc.volume6 += tripleProduct(t, ref);
                if (isDegenerate(t)) ++acc.degenerate;
            }
            return acc;
        },
        [](Sums a, const Sums& b) {
            a.area += b.area;
            a.volume6 += b.volume6;
            a.degenerate += b.degenerate;
            return a;
        });
    double volume6 = s.volume6;
    for (const Triangle& t : w.caps) volume6 += tripleProduct(t, ref);
    w.info.areaMm2 = s.area;
    // The divergence theorem gives +V for outward normals; ours point inward.
    w.info.enclosedVolumeMm3 = -volume6 / 6.0;
    check.degenerateFaces += s.degenerate;
    const int64_t chi = w.info.vertices - w.info.edges + w.info.faces;
    w.info.genus = (2 - w.info.boundaryLoops - chi) / 2;
}

/// Nesting: component c lies inside d when one of its vertices has winding number +-1 with
/// respect to d (capped). Only pairs whose bounding boxes nest are evaluated. A component
/// that holds few others gets the solid-angle sum over its faces per probe; one that holds
/// many (a part's outer surface around its voids) counts ray crossings instead
/// (ray_winding.h: the same integer, O(faces) once plus a few faces per probe), and any
/// probe whose rays are all too close to call gets the solid-angle sum.
void nestComponents(const TriMesh& mesh, const std::vector<std::vector<TriMesh::FaceHandle>>& componentFaces,
                    std::vector<ComponentWork>& work)
{
    for (std::size_t d = 0; d < work.size(); ++d) {
        std::vector<std::size_t> inside;
        for (std::size_t c = 0; c < work.size(); ++c)
            if (c != d && work[d].box.contains(work[c].box)) inside.push_back(c);
        if (inside.empty()) continue;
        const std::size_t faces = componentFaces[d].size() + work[d].caps.size();
        if (inside.size() * faces <= RAY_NESTING_MIN_WORK) {
            for (const std::size_t c : inside) {
                const double wn = windingNumber(mesh, componentFaces[d], work[d].caps, work[c].probe);
                if (std::fabs(wn) > 0.5) ++work[c].info.nestingDepth;
            }
            continue;
        }
        std::vector<std::size_t> undecided = inside;
        for (const auto& direction : RayWindingCounter::directions()) {
            if (undecided.empty()) break;
            const RayWindingCounter counter(mesh, componentFaces[d], work[d].caps, direction);
            std::vector<std::size_t> next;
            for (const std::size_t c : undecided) {
                const std::optional<int> wn = counter.winding(work[c].probe);
                if (!wn) next.push_back(c);
                else if (*wn != 0) ++work[c].info.nestingDepth;
            }
            undecided.swap(next);
        }
        for (const std::size_t c : undecided) {
            const double wn = windingNumber(mesh, componentFaces[d], work[d].caps, work[c].probe);
            if (std::fabs(wn) > 0.5) ++work[c].info.nestingDepth;
        }
    }
}

/// Adds the components to `check`'s totals and list, most faces first.
void addComponents(const std::vector<ComponentWork>& work, MeshCheck& check)
{
    std::vector<std::size_t> order(work.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return work[a].info.faces > work[b].info.faces;
    });
    for (const std::size_t c : order) {
        const MeshComponent& info = work[c].info;
        ++check.components;
        if (info.isClosed()) ++check.closedComponents;
        check.genus += info.genus;
        check.boundaryLoops += info.boundaryLoops;
        check.areaMm2 += info.areaMm2;
        check.enclosedVolumeMm3 += info.enclosedVolumeMm3;
        if (!info.hasInwardVolumeSign()) ++check.misorientedComponents;
        check.componentList.push_back(info);
    }
}

/// checkMesh with the vertex positions `pointAt(v)` (a Point3d) instead of the mesh's; without
/// `nesting` every component's nestingDepth stays 0 (the area and volume do not depend on it).
template<typename PointAt>
MeshCheck checkMeshAt(const TriMesh& mesh, const PointAt& pointAt, bool nesting)
{
    MeshCheck check;
    check.vertices = int64_t(mesh.n_vertices());
    check.edges = int64_t(mesh.n_edges());
    check.faces = int64_t(mesh.n_faces());

    std::vector<int> faceComponent;
    const std::vector<std::vector<TriMesh::FaceHandle>> componentFaces = faceComponents(mesh, faceComponent);
    std::vector<ComponentWork> work(componentFaces.size());
    countVerticesAndEdges(mesh, pointAt, faceComponent, work, check);
    capBoundaryLoops(mesh, pointAt, faceComponent, work);
    for (std::size_t c = 0; c < work.size(); ++c) measureComponent(mesh, pointAt, componentFaces[c], work[c], check);
    if (nesting) nestComponents(mesh, componentFaces, work);
    addComponents(work, check);
    return check;
}

} // namespace

MeshCheck checkMesh(const TriMesh& mesh)
{
    return checkMeshAt(mesh, [&](TriMesh::VertexHandle v) { return pointOf(mesh, v); }, true);
}

MeshMeasures measureMesh(const TriMesh& mesh, const std::vector<TriMesh::Point>& points)
{
    const MeshCheck check = checkMeshAt(
        mesh, [&](TriMesh::VertexHandle v) { return OpenMesh::vector_cast<Point3d>(points[std::size_t(v.idx())]); },
        false);
    return {check.areaMm2, check.enclosedVolumeMm3};
}

} // namespace flyover
