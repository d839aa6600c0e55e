#include "surface/lumen_surface.h"

#include "volume/seconds_since.h"

#include "surface/mesh_distance.h"
#include "volume/error.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace flyover {

namespace {

/// Reports a sub-step's progress as a slice [lo, hi] of the whole stage.
class SubProgress : public Progress {
public:
    SubProgress(Progress* parent, double lo, double hi) : mParent(parent), mLo(lo), mHi(hi) {}
    void update(double fraction, const std::string& what) override
    {
        mParent->update(mLo + (mHi - mLo) * fraction, what);
    }
    bool cancelled() const override { return mParent->cancelled(); }

private:
    Progress* mParent;
    double mLo, mHi;
};

std::optional<SubProgress> slice(Progress* parent, double lo, double hi)
{
    if (!parent) return std::nullopt;
    return SubProgress(parent, lo, hi);
}

Progress* ptr(std::optional<SubProgress>& p) { return p ? &*p : nullptr; }

} // namespace

int64_t restoreNonInwardFaces(TriMesh& mesh, const std::vector<TriMesh::Point>& extracted,
                              const openvdb::FloatGrid& sdf, FaceOrientation* orientation)
{
    std::vector<TriMesh::FaceHandle> bad;
    std::vector<FaceSide> badSides;
    FaceOrientation count = checkFaceOrientation(mesh, sdf, &bad, &badSides);
    if (orientation) *orientation = count;
    if (bad.empty()) return 0;
    // Each face's class while faces change (kept up to date in `count`): the first pass
    // classified the faces not listed as inward.
    std::vector<FaceSide> side(mesh.n_faces(), FaceSide::Inward);
    for (std::size_t i = 0; i < bad.size(); ++i) side[std::size_t(bad[i].idx())] = badSides[i];
    const LumenSideTest inward(sdf);
    int64_t restored = 0;
    std::vector<TriMesh::VertexHandle> moved;
    std::vector<char> queued(mesh.n_faces(), 0);
    while (!bad.empty()) {
        moved.clear();
        for (const TriMesh::FaceHandle f : bad)
            for (const auto v : mesh.fv_range(f)) {
                const TriMesh::Point& p = extracted[std::size_t(v.idx())];
                if (mesh.point(v) != p) {
                    mesh.set_point(v, p);
                    moved.push_back(v);
                }
            }
        restored += int64_t(moved.size());
        // Only faces around a restored vertex changed shape.
        bad.clear();
        for (const TriMesh::VertexHandle v : moved)
            for (const auto f : mesh.vf_range(v)) {
                if (queued[std::size_t(f.idx())]) continue;
                queued[std::size_t(f.idx())] = 1;
                std::array<OpenMesh::Vec3d, 3> p;
                int k = 0;
                for (const auto w : mesh.fv_range(f)) p[std::size_t(k++)] = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(w));
                const FaceSide now = inward.classify(p[0], p[1], p[2]);
                FaceSide& was = side[std::size_t(f.idx())];
                --count.of(was);
                ++count.of(now);
                was = now;
                if (now != FaceSide::Inward) bad.push_back(f);
            }
        for (const TriMesh::VertexHandle v : moved)
            for (const auto f : mesh.vf_range(v)) queued[std::size_t(f.idx())] = 0;
    }
    if (orientation) *orientation = count;
    return restored;
}

void validateMeshParams(const MeshParams& p)
{
    auto require = [](bool ok, const char* name, double value, const char* expected) {
        if (ok) return;
        std::ostringstream msg;
        msg << "MeshParams." << name << ": expected " << expected << ", got " << value;
        throw ParameterError(msg.str());
    };
    require(std::isfinite(p.isoValueMm), "isoValueMm", p.isoValueMm, "a finite value");
    require(p.adaptivity >= 0.0 && p.adaptivity <= 1.0, "adaptivity", p.adaptivity, "a value in [0, 1]");
    if (p.smoothMethod != "taubin" && p.smoothMethod != "none")
        throw ParameterError("MeshParams.smoothMethod: expected \"taubin\" or \"none\", got \"" +
                             p.smoothMethod + "\"");
    require(p.smoothIterations >= 0, "smoothIterations", p.smoothIterations, ">= 0");
    require(p.smoothPassBand > 0.0 && p.smoothPassBand < 1.0, "smoothPassBand", p.smoothPassBand,
            "a value in (0, 1)");
    require(p.decimateTargetFaces >= 0, "decimateTargetFaces", p.decimateTargetFaces, ">= 0");
    require(p.decimateFraction > 0.0 && p.decimateFraction <= 1.0, "decimateFraction", p.decimateFraction,
            "a value in (0, 1]");
    require(p.decimateMaxErrorVoxels >= 0.0 && std::isfinite(p.decimateMaxErrorVoxels), "decimateMaxErrorVoxels",
            p.decimateMaxErrorVoxels, "a finite value >= 0");
    require(p.decimateMaxNormalDeviationDeg > 0.0 && p.decimateMaxNormalDeviationDeg <= 180.0,
            "decimateMaxNormalDeviationDeg", p.decimateMaxNormalDeviationDeg, "a value in (0, 180]");
}

namespace {

/// The measures of the smoothed mesh, `current` being its check.
void measureSmoothed(const TriMesh& mesh, const MeshCheck& current, LumenSurfaceReport& rep)
{
    rep.smoothedVolumeMm3 = current.enclosedVolumeMm3;
    rep.smoothedRoughnessDeg = meanDihedralAngleDeg(mesh);
    if (rep.rawVolumeMm3 != 0.0)
        rep.smoothingVolumeChange = (rep.smoothedVolumeMm3 - rep.rawVolumeMm3) / rep.rawVolumeMm3;
}

/// The extraction's soup edge checks, when they were left for later (the soup is kept in
/// rep.extractedTriangles meanwhile).
void countSoupEdges(LumenSurfaceReport& rep)
{
    if (!rep.extractedTriangles) return;
    const auto [nonManifoldEdges, orientationConflicts] = countSoupEdgeProblems(*rep.extractedTriangles);
    rep.extraction.nonManifoldEdges = nonManifoldEdges;
    rep.extraction.orientationConflicts = orientationConflicts;
    rep.extractedTriangles.reset();
}

} // namespace

void checkLumenSurface(const TriMesh& mesh, const openvdb::FloatGrid& sdf, LumenSurfaceReport& rep)
{
    if (!rep.finalChecksPending) return;
    const auto t0 = std::chrono::steady_clock::now();
    countSoupEdges(rep);
    rep.check = checkMesh(mesh);
    // The raw (extracted) mesh's measures: its positions were kept when smoothing moved them,
    // else it is the mesh itself.
    if (rep.extractedPoints) {
        const MeshMeasures raw = measureMesh(mesh, *rep.extractedPoints);
        rep.rawAreaMm2 = raw.areaMm2;
        rep.rawVolumeMm3 = raw.enclosedVolumeMm3;
        rep.rawRoughnessDeg = meanDihedralAngleDeg(mesh, *rep.extractedPoints);
        rep.extractedPoints.reset();
    } else {
        rep.rawAreaMm2 = rep.check.areaMm2;
        rep.rawVolumeMm3 = rep.check.enclosedVolumeMm3;
        rep.rawRoughnessDeg = meanDihedralAngleDeg(mesh);
    }
    rep.smoothedVolumeMm3 = rep.rawVolumeMm3;
    rep.smoothedRoughnessDeg = rep.rawRoughnessDeg;
    if (rep.smoothed) measureSmoothed(mesh, rep.check, rep);
    if (!rep.orientationCounted) rep.orientation = checkFaceOrientation(mesh, sdf);
    rep.orientationCounted = false;
    rep.checkSeconds += secondsSince(t0);
    rep.finalChecksPending = false;
}

TriMesh makeLumenSurface(const openvdb::FloatGrid& sdf, const MeshParams& params, LumenSurfaceReport* report,
                         Progress* progress, bool measureDecimationError, bool deferFinalChecks)
{
    validateMeshParams(params);
    using Clock = std::chrono::steady_clock;
    LumenSurfaceReport rep;
    const openvdb::Vec3d voxel = sdf.voxelSize();
    const double voxelMm = std::min({voxel[0], voxel[1], voxel[2]});

    // The soup's edge checks wait with the final checks, unless decimation may run (which
    // makes those checks at once).
    const bool mayDecimate = params.decimateTargetFaces > 0 || params.decimateFraction < 1.0 ||
                             params.decimateMaxErrorVoxels > 0.0;

    auto t0 = Clock::now();
    auto extractProgress = slice(progress, 0.0, 0.3);
    // With the final checks deferred (the pipeline's mesh stage, on the first pair's path), the
    // extraction's surface-wide measures no report shows are left out: the counts only; its
    // soup's edge checks wait with the final checks.
    TriMesh mesh = extractSurface(sdf, params, &rep.extraction, ptr(extractProgress), !deferFinalChecks,
                                  deferFinalChecks && !mayDecimate ? &rep.extractedTriangles : nullptr);
    rep.extractSeconds = secondsSince(t0);

    int64_t target = 0;
    if (params.decimateTargetFaces > 0) target = params.decimateTargetFaces;
    if (params.decimateFraction < 1.0) {
        const auto byFraction = int64_t(std::llround(params.decimateFraction * double(mesh.n_faces())));
        target = target > 0 ? std::min(target, byFraction) : std::max<int64_t>(byFraction, 1);
    }
    rep.decimationMaxErrorMm = params.decimateMaxErrorVoxels * voxelMm;
    const bool decimating = target > 0 || rep.decimationMaxErrorMm > 0.0;
    const bool later = deferFinalChecks && !decimating;
    if (!later) countSoupEdges(rep);

    // The check of the mesh as it stands; reused as the final check when nothing changes it.
    // Deferred, the raw measures are taken later by checkLumenSurface() (from the extracted
    // positions, kept in the report, when smoothing moves the vertices).
    MeshCheck current;
    if (!later) {
        t0 = Clock::now();
        reportProgress(progress, 0.3, "raw mesh measures");
        current = checkMesh(mesh);
        rep.rawAreaMm2 = current.areaMm2;
        rep.rawVolumeMm3 = current.enclosedVolumeMm3;
        rep.rawRoughnessDeg = meanDihedralAngleDeg(mesh);
        rep.checkSeconds += secondsSince(t0);
    }

    rep.smoothedVolumeMm3 = rep.rawVolumeMm3;
    rep.smoothedRoughnessDeg = rep.rawRoughnessDeg;
    if (params.smoothMethod == "taubin" && params.smoothIterations > 0) {
        rep.smoothed = true;
        t0 = Clock::now();
        TaubinParams taubin;
        taubin.iterations = params.smoothIterations;
        taubin.passBand = params.smoothPassBand;
        auto smoothProgress = slice(progress, 0.35, 0.5);
        auto extracted = std::make_shared<std::vector<TriMesh::Point>>(mesh.n_vertices());
        for (const auto v : mesh.vertices()) (*extracted)[std::size_t(v.idx())] = mesh.point(v);
        smoothMeshTaubin(mesh, taubin, &rep.smoothing, ptr(smoothProgress));
        rep.smoothingRestoredVertices = restoreNonInwardFaces(mesh, *extracted, sdf, &rep.orientation);
        rep.orientationCounted = true;
        if (later) rep.extractedPoints = std::move(extracted);
        rep.smoothSeconds = secondsSince(t0);
        if (!later) {
            t0 = Clock::now();
            current = checkMesh(mesh);
            measureSmoothed(mesh, current, rep);
            rep.checkSeconds += secondsSince(t0);
        }
    }

    rep.decimation.facesBefore = rep.decimation.facesAfter = int64_t(mesh.n_faces());
    if (decimating) {
        rep.orientationCounted = false;  // decimation changes the faces
        t0 = Clock::now();
        std::optional<TriMesh> before;
        if (measureDecimationError) before = mesh;
        DecimateParams decimate;
        decimate.targetFaces = target;
        decimate.maxErrorMm = rep.decimationMaxErrorMm;
        decimate.maxNormalDeviationDeg = params.decimateMaxNormalDeviationDeg;
        const LumenSideTest inward(sdf);  // decimation runs serially: one instance suffices
        decimate.acceptTriangle = [&inward](const OpenMesh::Vec3d& a, const OpenMesh::Vec3d& b,
                                            const OpenMesh::Vec3d& c) { return inward.isInward(a, b, c); };
        auto decimateProgress = slice(progress, 0.5, 0.75);
        decimateMesh(mesh, decimate, &rep.decimation, ptr(decimateProgress));
        rep.decimateSeconds = secondsSince(t0);
        if (before && rep.decimation.collapses > 0) {
            t0 = Clock::now();
            reportProgress(progress, 0.75, "decimation error");
            // Samples every half voxel: the extracted faces are about that size (so their vertices
            // and centroids are sampled), the decimated ones get a lattice (mesh_distance.h).
            rep.decimationHausdorffMm = hausdorffDistanceMm(*before, mesh, 0.5 * voxelMm);
            rep.checkSeconds += secondsSince(t0);
        }
    }

    if (later) {
        // checkLumenSurface() measures the final mesh (here: the smoothed one) later.
        rep.finalChecksPending = true;
    } else {
        t0 = Clock::now();
        reportProgress(progress, 0.85, "mesh checks");
        rep.check = rep.decimation.collapses > 0 ? checkMesh(mesh) : std::move(current);
        if (!rep.orientationCounted) rep.orientation = checkFaceOrientation(mesh, sdf);
        rep.orientationCounted = false;
        rep.checkSeconds += secondsSince(t0);
    }
    reportProgress(progress, 1.0, "mesh done");
    if (report) *report = rep;
    return mesh;
}

} // namespace flyover
