#include "inspect/part_surface.h"

#include "volume/error.h"

#include <openvdb/tools/Morphology.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/combinable.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <optional>
#include <string>

namespace flyover {

namespace {

/// Marks in `out` every voxel (and tile) of `grid` whose value passes `on`.
template <typename GridT, typename Pred> void markVoxels(const GridT& grid, openvdb::BoolGrid& out, Pred on)
{
    auto acc = out.getAccessor();
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        if (!on(*it)) continue;
        if (it.isVoxelValue()) acc.setValueOn(it.getCoord(), true);
        else out.tree().fill(it.getBoundingBox(), true, true);
    }
}

struct MaterialAirStats {
    double materialSum = 0, airSum = 0;
    int64_t material = 0, air = 0;
};

} // namespace

int PartSurface::voidOfFace(int64_t face) const
{
    // Ranges are ordered and contiguous after the outer surface.
    if (face < outer.first + outer.count) return 0;
    int lo = 0, hi = int(voids.size()) - 1;
    while (lo <= hi) {
        const int mid = (lo + hi) / 2;
        if (face < voids[std::size_t(mid)].first) hi = mid - 1;
        else if (face >= voids[std::size_t(mid)].first + voids[std::size_t(mid)].count) lo = mid + 1;
        else return mid + 1;
    }
    return 0;
}

void validatePartSurfaceParams(const PartSurfaceParams& params)
{
    if (params.smoothIterations < 0) throw ParameterError("surfaces.smooth_iterations: must be >= 0");
    if (!(params.smoothPassBand > 0 && params.smoothPassBand < 1))
        throw ParameterError("surfaces.smooth_pass_band: must be in (0, 1)");
}

PartField makePartField(const openvdb::FloatGrid& ct, const PartAnalysis& analysis, Progress* progress)
{
    if (!analysis.material || analysis.material->activeVoxelCount() == 0)
        throw InputError("part surface: the analysis holds no material");
    using openvdb::Coord;
    const double vox = ct.voxelSize()[0];
    const openvdb::CoordBBox box = ct.evalActiveVoxelBoundingBox();

    // Air that gets a surface: the outside air (bores and open cracks included) and the listed
    // voids. Everything else in the scan's box is solid for the mesh: material and small voids.
    auto air = openvdb::BoolGrid::create(false);
    // A BoolGrid mask is its active topology (analysePart's values may all be false).
    if (analysis.outsideAir) markVoxels(*analysis.outsideAir, *air, [](bool) { return true; });
    if (analysis.voidLabels) markVoxels(*analysis.voidLabels, *air, [](int32_t v) { return v > 0; });
    auto solid = openvdb::BoolGrid::create(false);
    solid->tree().fill(box, true, true);
    solid->tree().topologyDifference(air->tree());
    reportProgress(progress, 0.05, "solid and air");

    // The narrow band: two voxels either side of the solid's boundary; the solid's core (deeper
    // inside) is inactive with the inside value. The sign of every inactive value is set here
    // explicitly: signedFloodFill cannot be trusted with a core made of large tiles (a tile's
    // sign comes from its neighbours in scan order, which may lie outside the part).
    auto band = openvdb::BoolGrid::create(false);
    band->tree().topologyUnion(solid->tree());
    openvdb::tools::dilateActiveValues(band->tree(), 2, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::EXPAND_TILES);
    auto core = openvdb::BoolGrid::create(false);
    core->tree().topologyUnion(solid->tree());
    openvdb::tools::erodeActiveValues(core->tree(), 2, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                      openvdb::tools::EXPAND_TILES);
    band->tree().topologyDifference(core->tree());
    const float bandMm = float(2.5 * vox);
    auto field = openvdb::FloatGrid::create(bandMm);
    field->setTransform(ct.transform().copy());
    field->setGridClass(openvdb::GRID_LEVEL_SET);
    field->setName("part_field");
    {
        auto acc = field->getAccessor();
        for (auto it = core->cbeginValueOn(); it; ++it) {
            if (it.isVoxelValue()) acc.setValueOff(it.getCoord(), -bandMm);
            else field->tree().fill(it.getBoundingBox(), -bandMm, false);
        }
    }
    field->tree().topologyUnion(band->tree());
    field->tree().voxelizeActiveTiles();
    reportProgress(progress, 0.1, "narrow band");

    // Half the contrast between material and air, from the band's voxels.
    const double threshold = analysis.threshold;
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(field->tree());
    tbb::combinable<MaterialAirStats> stats;
    leaves.foreach([&](const openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        auto ctAcc = ct.getConstAccessor();
        auto solidAcc = solid->getConstAccessor();
        MaterialAirStats& s = stats.local();
        for (auto it = leaf.cbeginValueOn(); it; ++it) {
            const Coord ijk = it.getCoord();
            if (!box.isInside(ijk)) continue;
            const double g = ctAcc.getValue(ijk);
            if (solidAcc.isValueOn(ijk) && g >= threshold) {
                s.materialSum += g;
                ++s.material;
            } else if (!solidAcc.isValueOn(ijk) && g < threshold) {
                s.airSum += g;
                ++s.air;
            }
        }
    }, true);
    const MaterialAirStats total = stats.combine([](const MaterialAirStats& a, const MaterialAirStats& b) {
        return MaterialAirStats{a.materialSum + b.materialSum, a.airSum + b.airSum, a.material + b.material, a.air + b.air};
    });
    const double materialMean = total.material > 0 ? total.materialSum / double(total.material) : threshold + 1;
    const double airMean = total.air > 0 ? total.airSum / double(total.air) : threshold - 1;
    const double halfContrast = std::max(0.5 * (materialMean - airMean), 1e-6 * std::max(1.0, std::abs(threshold)));

    // Field values in mm: (threshold - grey) / half-contrast voxels, clamped to the band, the
    // sign forced to agree with the analysis at every voxel centre.
    const float minMag = float(0.05 * vox);
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        auto ctAcc = ct.getConstAccessor();
        auto solidAcc = solid->getConstAccessor();
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const Coord ijk = it.getCoord();
            const double g = box.isInside(ijk) ? double(ctAcc.getValue(ijk)) : airMean;
            float v = float(std::clamp((threshold - g) / halfContrast * vox, -2.0 * vox, 2.0 * vox));
            if (solidAcc.isValueOn(ijk)) v = std::min(v, -minMag);
            else v = std::max(v, minMag);
            it.setValue(v);
        }
    });
    reportProgress(progress, 0.2, "field");
    PartField out;
    out.field = field;
    out.air = air;
    out.box = box;
    out.transform = ct.transform().copy();
    out.halfContrast = halfContrast;
    return out;
}

PartSurface meshPartField(PartField&& partField, const PartAnalysis& analysis, const PartSurfaceParams& params,
                          Progress* progress)
{
    validatePartSurfaceParams(params);
    using openvdb::Coord;
    const openvdb::math::Transform& xf = *partField.transform;
    const double vox = xf.voxelSize()[0];
    const openvdb::CoordBBox box = partField.box;
    const openvdb::BoolGrid::Ptr air = partField.air;
    MeshParams mp;
    mp.smoothMethod = params.smoothIterations > 0 ? "taubin" : "none";
    mp.smoothIterations = params.smoothIterations;
    mp.smoothPassBand = params.smoothPassBand;
    PartSurface out;
    out.halfContrast = partField.halfContrast;
    TriMesh mesh;
    {
        struct Sub : Progress {
            Progress* parent;
            explicit Sub(Progress* p) : parent(p) {}
            void update(double f, const std::string& what) override { parent->update(0.2 + 0.7 * f, what); }
            bool cancelled() const override { return parent->cancelled(); }
        };
        std::optional<Sub> sub;
        if (progress) sub.emplace(progress);
        mesh = makeLumenSurface(*partField.field, mp, &out.report, sub ? &*sub : nullptr, false);
    }
    partField.field.reset();  // the narrow band is not needed any more

    // Which void each connected component bounds: a vote of its faces, each looking up the air
    // just beside it (against its normal, which points into the material).
    const int nVoids = int(analysis.voids.size());
    std::vector<int> faceComponent(mesh.n_faces(), -1);
    std::vector<std::map<int, int64_t>> votes;
    {
        openvdb::Int32Grid::Ptr noLabels = analysis.voidLabels ? nullptr : openvdb::Int32Grid::create(0);
        const openvdb::Int32Grid& labels = analysis.voidLabels ? *analysis.voidLabels : *noLabels;
        auto lab = labels.getConstAccessor();
        auto outside = air->getConstAccessor();
        std::vector<TriMesh::FaceHandle> stack;
        for (const auto f0 : mesh.faces()) {
            if (faceComponent[std::size_t(f0.idx())] >= 0) continue;
            const int comp = int(votes.size());
            votes.emplace_back();
            stack.assign(1, f0);
            faceComponent[std::size_t(f0.idx())] = comp;
            while (!stack.empty()) {
                const TriMesh::FaceHandle f = stack.back();
                stack.pop_back();
                std::array<OpenMesh::Vec3d, 3> p;
                int k = 0;
                for (const auto v : mesh.fv_range(f)) p[std::size_t(k++)] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v));
                OpenMesh::Vec3d n = (p[1] - p[0]) % (p[2] - p[0]);
                const double len = n.norm();
                if (len > 0) {
                    n /= len;
                    const OpenMesh::Vec3d c = (p[0] + p[1] + p[2]) / 3.0;
                    int vote = -1;
                    for (double s : {0.35, 0.7, 1.05, 1.4}) {
                        const OpenMesh::Vec3d q = c - n * (s * vox);
                        const Coord ijk = xf.worldToIndexCellCentered(openvdb::Vec3d(q[0], q[1], q[2]));
                        const int32_t l = lab.getValue(ijk);
                        if (l > 0 && l <= nVoids) { vote = l; break; }
                        if (!box.isInside(ijk) || outside.isValueOn(ijk)) { vote = 0; break; }
                    }
                    ++votes[std::size_t(comp)][vote];
                }
                for (const auto g : mesh.ff_range(f))
                    if (faceComponent[std::size_t(g.idx())] < 0) {
                        faceComponent[std::size_t(g.idx())] = comp;
                        stack.push_back(g);
                    }
            }
        }
    }
    std::vector<int> componentVoid(votes.size(), 0);
    for (std::size_t c = 0; c < votes.size(); ++c) {
        int best = -1;
        int64_t bestCount = -1;
        for (const auto& [label, count] : votes[c])
            if (label >= 0 && count > bestCount) { best = label; bestCount = count; }
        componentVoid[c] = std::max(best, 0);
        if (best < 0)  // no face of the component saw outside air or a listed void
            for (const auto& [label, count] : votes[c]) out.unassignedFaces += count;
    }

    // The mesh again with its faces grouped: outer surface, then void 1, 2, ... Components are
    // disjoint and keep their own face order, so OpenMesh rebuilds each exactly.
    // Built from compact copies (points, and the faces' vertex indices in group order) after
    // the first mesh is freed, so two OpenMesh meshes (~150 B a face each) are never held at once.
    std::vector<int64_t> groupStart(std::size_t(nVoids) + 2, 0);
    for (const auto f : mesh.faces())
        ++groupStart[std::size_t(componentVoid[std::size_t(faceComponent[std::size_t(f.idx())])]) + 1];
    for (std::size_t g = 1; g < groupStart.size(); ++g) groupStart[g] += groupStart[g - 1];
    std::vector<std::array<int, 3>> faceVertices(mesh.n_faces());
    {
        std::vector<int64_t> next(groupStart.begin(), groupStart.end() - 1);
        for (const auto f : mesh.faces()) {
            const int g = componentVoid[std::size_t(faceComponent[std::size_t(f.idx())])];
            std::array<int, 3>& fv = faceVertices[std::size_t(next[std::size_t(g)]++)];
            int k = 0;
            for (const auto v : mesh.fv_range(f)) fv[std::size_t(k++)] = v.idx();
        }
    }
    std::vector<TriMesh::Point> points;
    points.reserve(mesh.n_vertices());
    for (const auto v : mesh.vertices()) points.push_back(mesh.point(v));
    const std::size_t nEdges = mesh.n_edges();
    std::vector<int>().swap(faceComponent);
    mesh = TriMesh();  // frees its storage
    out.mesh.reserve(points.size(), nEdges, faceVertices.size());
    for (const auto& p : points) out.mesh.add_vertex(p);
    std::vector<TriMesh::Point>().swap(points);
    out.voids.resize(std::size_t(nVoids));
    int64_t failed = 0;
    for (std::size_t g = 0; g + 1 < groupStart.size(); ++g) {
        FaceRange& range = g == 0 ? out.outer : out.voids[g - 1];
        range.first = int64_t(out.mesh.n_faces());
        for (int64_t i = groupStart[g]; i < groupStart[g + 1]; ++i) {
            const std::array<int, 3>& fv = faceVertices[std::size_t(i)];
            if (!out.mesh.add_face(out.mesh.vertex_handle(fv[0]), out.mesh.vertex_handle(fv[1]), out.mesh.vertex_handle(fv[2]))
                     .is_valid())
                ++failed;
        }
        range.count = int64_t(out.mesh.n_faces()) - range.first;
    }
    if (failed > 0)
        throw std::runtime_error("part surface: " + std::to_string(failed) + " faces could not be re-added after grouping");
    reportProgress(progress, 1.0, "surfaces");
    return out;
}

PartSurface makePartSurface(const openvdb::FloatGrid& ct, const PartAnalysis& analysis,
                            const PartSurfaceParams& params, Progress* progress)
{
    validatePartSurfaceParams(params);
    return meshPartField(makePartField(ct, analysis, progress), analysis, params, progress);
}

} // namespace flyover
