// GCC 12 reports -Wmaybe-uninitialized inside OpenMesh's property code (see extract_surface.cpp).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "surface/mesh_build.h"

#include "volume/error.h"

#include <string>
#include <utility>
#pragma GCC diagnostic pop

namespace flyover {

namespace {

constexpr int NONE = -1;

/// One halfedge as OpenMesh's ArrayKernel holds it; halfedge h's opposite is h ^ 1 and its
/// edge h / 2 (new_edge makes 2e from start to end, 2e + 1 back).
struct HalfedgeRec {
    int face = NONE;
    int to = NONE;
    int next = NONE;
    int prev = NONE;
};

/// PolyConnectivity::add_face (OpenMesh 8/9) for a triangle, on flat arrays: the same tests in
/// the same order, the same next-link cache applied in the same order, the same vertex
/// halfedge updates. Circulation around a vertex is OpenMesh's default (clockwise: the next
/// outgoing halfedge is next(opposite(h))).
class Builder {
public:
    explicit Builder(std::size_t vertices, std::size_t faces) : vertexHe_(vertices, NONE)
    {
        he_.reserve(faces * 3 + 32);
        faceHe_.reserve(faces);
    }

    bool addFace(const int* v)
    {
        constexpr int n = 3;
        int heh[n];
        bool isNew[n], needsAdjust[n];
        for (int i = 0, ii = 1; i < n; ++i, ++ii, ii %= n) {
            if (!isBoundaryVertex(v[i])) return false; // complex vertex
            heh[i] = findHalfedge(v[i], v[ii]);
            isNew[i] = heh[i] == NONE;
            needsAdjust[i] = false;
            if (!isNew[i] && he_[std::size_t(heh[i])].face != NONE) return false; // complex edge
        }

        // At most 3 relinks x 3 + 3 x (2 + 1) pairs for a triangle.
        std::pair<int, int> cache[18];
        int cached = 0;
        for (int i = 0, ii = 1; i < n; ++i, ++ii, ii %= n) {
            if (isNew[i] || isNew[ii]) continue;
            const int innerPrev = heh[i], innerNext = heh[ii];
            if (next(innerPrev) == innerNext) continue;
            const int outerPrev = innerNext ^ 1;
            int boundaryPrev = outerPrev;
            do boundaryPrev = next(boundaryPrev) ^ 1;
            while (he_[std::size_t(boundaryPrev)].face != NONE);
            const int boundaryNext = next(boundaryPrev);
            if (boundaryPrev == innerPrev) return false; // patch re-linking failed
            const int patchStart = next(innerPrev), patchEnd = prev(innerNext);
            cache[cached++] = {boundaryPrev, patchStart};
            cache[cached++] = {patchEnd, boundaryNext};
            cache[cached++] = {innerPrev, innerNext};
        }

        for (int i = 0, ii = 1; i < n; ++i, ++ii, ii %= n)
            if (isNew[i]) heh[i] = newEdge(v[i], v[ii]);

        const int fh = int(faceHe_.size());
        faceHe_.push_back(heh[n - 1]);

        for (int i = 0, ii = 1; i < n; ++i, ++ii, ii %= n) {
            const int vh = v[ii];
            const int innerPrev = heh[i], innerNext = heh[ii];
            const int id = (isNew[i] ? 1 : 0) | (isNew[ii] ? 2 : 0);
            if (id) {
                const int outerPrev = innerNext ^ 1, outerNext = innerPrev ^ 1;
                switch (id) {
                case 1: // prev is new, next is old
                    cache[cached++] = {prev(innerNext), outerNext};
                    vertexHe_[std::size_t(vh)] = outerNext;
                    break;
                case 2: { // next is new, prev is old
                    const int boundaryNext = next(innerPrev);
                    cache[cached++] = {outerPrev, boundaryNext};
                    vertexHe_[std::size_t(vh)] = boundaryNext;
                    break;
                }
                default: // both are new
                    if (vertexHe_[std::size_t(vh)] == NONE) {
                        vertexHe_[std::size_t(vh)] = outerNext;
                        cache[cached++] = {outerPrev, outerNext};
                    } else {
                        const int boundaryNext = vertexHe_[std::size_t(vh)];
                        cache[cached++] = {prev(boundaryNext), outerNext};
                        cache[cached++] = {outerPrev, boundaryNext};
                    }
                    break;
                }
                cache[cached++] = {innerPrev, innerNext};
            } else {
                needsAdjust[ii] = vertexHe_[std::size_t(vh)] == innerNext;
            }
            he_[std::size_t(heh[i])].face = fh;
        }

        for (int i = 0; i < cached; ++i) {
            he_[std::size_t(cache[i].first)].next = cache[i].second;
            he_[std::size_t(cache[i].second)].prev = cache[i].first;
        }

        for (int i = 0; i < n; ++i)
            if (needsAdjust[i]) adjustOutgoing(v[i]);
        return true;
    }

    /// Copies the connectivity into `mesh` (its vertices already there).
    void copyInto(TriMesh& mesh) const
    {
        mesh.resize(vertexHe_.size(), he_.size() / 2, faceHe_.size());
        for (std::size_t v = 0; v < vertexHe_.size(); ++v)
            mesh.set_halfedge_handle(TriMesh::VertexHandle(int(v)), TriMesh::HalfedgeHandle(vertexHe_[v]));
        // set_next_halfedge_handle also writes the next one's prev; the prevs are written again
        // after, as they are. A prev never set has no halfedge whose next is it, so stays unset.
        for (std::size_t h = 0; h < he_.size(); ++h) {
            const TriMesh::HalfedgeHandle heh{int(h)};
            const HalfedgeRec& r = he_[h];
            mesh.set_vertex_handle(heh, TriMesh::VertexHandle(r.to));
            mesh.set_face_handle(heh, TriMesh::FaceHandle(r.face));
            if (r.next != NONE) mesh.set_next_halfedge_handle(heh, TriMesh::HalfedgeHandle(r.next));
        }
        for (std::size_t h = 0; h < he_.size(); ++h)
            if (he_[h].prev != NONE)
                mesh.set_prev_halfedge_handle(TriMesh::HalfedgeHandle(int(h)), TriMesh::HalfedgeHandle(he_[h].prev));
        for (std::size_t f = 0; f < faceHe_.size(); ++f)
            mesh.set_halfedge_handle(TriMesh::FaceHandle(int(f)), TriMesh::HalfedgeHandle(faceHe_[f]));
    }

private:
    int next(int h) const { return he_[std::size_t(h)].next; }
    int prev(int h) const { return he_[std::size_t(h)].prev; }

    bool isBoundaryVertex(int v) const
    {
        const int h = vertexHe_[std::size_t(v)];
        return h == NONE || he_[std::size_t(h)].face == NONE;
    }

    /// find_halfedge: the outgoing halfedges of `a`, clockwise from its halfedge, once round.
    int findHalfedge(int a, int b) const
    {
        const int start = vertexHe_[std::size_t(a)];
        if (start == NONE) return NONE;
        int h = start;
        do {
            if (he_[std::size_t(h)].to == b) return h;
            h = next(h ^ 1);
        } while (h != start && h != NONE);
        return NONE;
    }

    /// adjust_outgoing_halfedge: the first boundary halfedge in the same circulation.
    void adjustOutgoing(int v)
    {
        const int start = vertexHe_[std::size_t(v)];
        if (start == NONE) return;
        int h = start;
        do {
            if (he_[std::size_t(h)].face == NONE) {
                vertexHe_[std::size_t(v)] = h;
                return;
            }
            h = next(h ^ 1);
        } while (h != start && h != NONE);
    }

    int newEdge(int start, int end)
    {
        const int h = int(he_.size());
        he_.push_back({NONE, end, NONE, NONE});
        he_.push_back({NONE, start, NONE, NONE});
        return h;
    }

    std::vector<int> vertexHe_;
    std::vector<HalfedgeRec> he_;
    std::vector<int> faceHe_;
};

} // namespace

int64_t addFacesLikeOpenMesh(TriMesh& mesh, const std::vector<std::array<int, 3>>& faces)
{
    if (mesh.n_edges() != 0 || mesh.n_faces() != 0)
        throw ParameterError("addFacesLikeOpenMesh: expected a mesh with vertices only, got " +
                             std::to_string(mesh.n_edges()) + " edges and " +
                             std::to_string(mesh.n_faces()) + " faces");
    const int nv = int(mesh.n_vertices());
    Builder builder(mesh.n_vertices(), faces.size());
    int64_t refused = 0;
    for (const std::array<int, 3>& f : faces) {
        for (const int v : f)
            if (v < 0 || v >= nv)
                throw ParameterError("addFacesLikeOpenMesh: vertex index " + std::to_string(v) +
                                     " outside the mesh's " + std::to_string(nv) + " vertices");
        if (f[0] == f[1] || f[1] == f[2] || f[0] == f[2] || !builder.addFace(f.data())) ++refused;
    }
    builder.copyInto(mesh);
    return refused;
}

} // namespace flyover
