#include "surface/smooth_mesh.h"

#include "volume/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <sstream>
#include <string>
#include <vector>

namespace flyover {

namespace {

using Vec3d = OpenMesh::Vec3d;

/// Vertex adjacency in compressed rows: the neighbours of v are
/// neighbours[offsets[v] .. offsets[v + 1]); fixed vertices have none.
struct Adjacency {
    std::vector<std::size_t> offsets;
    std::vector<int> neighbours;
};

Adjacency buildAdjacency(const TriMesh& mesh, int64_t& fixedVertices)
{
    // Parallel over vertices (the mesh is only read): the valences, their prefix sums (serial,
    // cheap), then each vertex's neighbours in its circulation order, as a serial build lists them.
    const std::size_t n = mesh.n_vertices();
    const bool hasStatus = mesh.has_vertex_status();  // deleted vertices: skipped, as mesh.vertices() does
    Adjacency a;
    a.offsets.assign(n + 1, 0);
    fixedVertices = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, 4096), int64_t(0),
        [&](const tbb::blocked_range<std::size_t>& r, int64_t fixed) {
            for (std::size_t v = r.begin(); v != r.end(); ++v) {
                const TriMesh::VertexHandle vh{int(v)};
                if (hasStatus && mesh.status(vh).deleted()) continue;
                const std::size_t valence = mesh.valence(vh);
                const bool movable = !mesh.is_boundary(vh) && mesh.is_manifold(vh) && valence > 0;
                a.offsets[v + 1] = movable ? valence : 0;
                if (!movable) ++fixed;
            }
            return fixed;
        },
        [](int64_t x, int64_t y) { return x + y; });
    for (std::size_t i = 1; i < a.offsets.size(); ++i) a.offsets[i] += a.offsets[i - 1];
    a.neighbours.resize(a.offsets.back());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t v = r.begin(); v != r.end(); ++v) {
            std::size_t k = a.offsets[v];
            if (k == a.offsets[v + 1]) continue;  // fixed
            for (const auto w : mesh.vv_range(TriMesh::VertexHandle{int(v)})) a.neighbours[k++] = w.idx();
        }
    });
    return a;
}

/// One Jacobi step in + weight * L(in) -> out.
void umbrellaStep(const Adjacency& a, const std::vector<Vec3d>& in, std::vector<Vec3d>& out, double weight)
{
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, in.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t v = r.begin(); v != r.end(); ++v) {
                              const std::size_t b = a.offsets[v], e = a.offsets[v + 1];
                              if (b == e) {
                                  out[v] = in[v];
                                  continue;
                              }
                              Vec3d mean(0.0);
                              for (std::size_t k = b; k != e; ++k) mean += in[std::size_t(a.neighbours[k])];
                              mean /= double(e - b);
                              out[v] = in[v] + weight * (mean - in[v]);
                          }
                      });
}

} // namespace

void smoothMeshTaubin(TriMesh& mesh, const TaubinParams& params, SmoothReport* report, Progress* progress)
{
    auto fail = [](const std::string& name, double value, const char* expected) {
        std::ostringstream msg;
        msg << "TaubinParams." << name << ": expected " << expected << ", got " << value;
        throw ParameterError(msg.str());
    };
    if (!(params.iterations >= 0)) fail("iterations", params.iterations, "an integer >= 0");
    if (!(params.passBand > 0.0 && params.passBand < 1.0)) fail("passBand", params.passBand, "a value in (0, 1)");
    if (!(params.lambda > 0.0 && params.lambda < 1.0)) fail("lambda", params.lambda, "a value in (0, 1)");

    SmoothReport rep;
    const Adjacency adjacency = buildAdjacency(mesh, rep.fixedVertices);
    // Positions in double: hundreds of small steps in float would drift by rounding.
    std::vector<Vec3d> original(mesh.n_vertices());
    for (const auto v : mesh.vertices()) original[std::size_t(v.idx())] = OpenMesh::vector_cast<Vec3d>(mesh.point(v));
    std::vector<Vec3d> p = original, tmp(p.size());
    const double mu = params.mu();
    for (int i = 0; i < params.iterations; ++i) {
        reportProgress(progress, double(i) / double(params.iterations), "Taubin smoothing");
        umbrellaStep(adjacency, p, tmp, params.lambda);
        umbrellaStep(adjacency, tmp, p, mu);
    }

    struct Moved {
        double max2 = 0, sum2 = 0;
    };
    const Moved moved = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, p.size(), 4096), Moved{},
        [&](const tbb::blocked_range<std::size_t>& r, Moved acc) {
            for (std::size_t v = r.begin(); v != r.end(); ++v) {
                const double d2 = (p[v] - original[v]).sqrnorm();
                acc.max2 = std::max(acc.max2, d2);
                acc.sum2 += d2;
            }
            return acc;
        },
        [](Moved a, const Moved& b) {
            a.max2 = std::max(a.max2, b.max2);
            a.sum2 += b.sum2;
            return a;
        });
    for (const auto v : mesh.vertices()) mesh.set_point(v, OpenMesh::vector_cast<TriMesh::Point>(p[std::size_t(v.idx())]));
    rep.maxDisplacementMm = std::sqrt(moved.max2);
    rep.rmsDisplacementMm = p.empty() ? 0.0 : std::sqrt(moved.sum2 / double(p.size()));
    reportProgress(progress, 1.0, "Taubin smoothing done");
    if (report) *report = rep;
}

} // namespace flyover
