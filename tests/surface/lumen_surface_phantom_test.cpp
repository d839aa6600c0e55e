// The one full-size test (style: CI runs the suite in < 25 min on 2 cores, so everything
// else runs on analytic shapes): the full-size phantom through ingest and segmentation, then
// the mesh stage's sequence three ways (raw, default smoothing, decimated to half), measured
// against the phantom's truth.
#include "surface/lumen_surface.h"

#include "colon/phantom.h"
#include "tests/shapes/surface_shapes.h"
#include "volume/ingest.h"
#include "colon/segment.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

namespace flyover {
namespace {

OpenMesh::Vec3d om(const Vec3d& v) { return OpenMesh::Vec3d(v.x, v.y, v.z); }

/// The polyp's site on the true centerline: the point whose arc length is the polyp's.
test::PolypSite polypSite(const PhantomTruth& truth, const PhantomPolyp& polyp)
{
    const std::vector<Vec3d>& line = truth.centerlineMm;
    std::size_t best = 0;
    double arc = 0, bestGap = std::numeric_limits<double>::max();
    for (std::size_t i = 0; i < line.size(); ++i) {
        if (i > 0) arc += distance(line[i], line[i - 1]);
        if (std::fabs(arc - polyp.arcMm) < bestGap) {
            bestGap = std::fabs(arc - polyp.arcMm);
            best = i;
        }
    }
    const std::size_t a = best >= 2 ? best - 2 : 0, b = std::min(best + 2, line.size() - 1);
    test::PolypSite s;
    s.axisMm = om(line[best]);
    s.tangent = om(normalize(line[b] - line[a]));
    s.outwardDir = om(polyp.outwardDir);
    s.centreMm = om(polyp.centerMm);
    s.radiusMm = polyp.radiusMm;
    s.tubeRadiusMm = truth.radiusMm[best];
    return s;
}

void expectSoundPhantomSurface(const LumenSurfaceReport& r)
{
    EXPECT_EQ(r.orientation.inward, r.check.faces) << "100% of faces inward";
    EXPECT_EQ(r.orientation.outward, 0);
    EXPECT_EQ(r.orientation.noGradient, 0);
    EXPECT_EQ(r.check.misorientedComponents, 0) << "enclosed volume sign of every component";
    EXPECT_EQ(r.check.nonManifoldVertices, 0);
    EXPECT_EQ(r.extraction.nonManifoldEdges, 0);
    EXPECT_EQ(r.extraction.droppedFaces, 0);
    EXPECT_EQ(r.extraction.orientationConflicts, 0);
    EXPECT_EQ(r.check.degenerateFaces, 0);
    EXPECT_TRUE(r.isSound());
}

TEST(LumenSurfacePhantom, FullSizeIsInwardManifoldFaithfulAndDecimatable)
{
    const auto start = std::chrono::steady_clock::now();
    PhantomParams pp;
    pp.size = PhantomSize::Full;
    pp.seed = 1;
    openvdb::FloatGrid::Ptr sdf;
    PhantomTruth truth;
    double voxelMm = 0;
    {
        const Phantom phantom = makePhantom(pp);
        truth = phantom.truth;
        Image3<float> image;
        image.geometry = phantom.ct.geometry;
        image.voxels.assign(phantom.ct.voxels.begin(), phantom.ct.voxels.end());
        const auto hu = ingestImage(image, IngestParams{});
        image = {};
        sdf = segmentLumen(*hu, SegmentParams{}).sdf;
        voxelMm = sdf->voxelSize()[0];
    }
    SCOPED_TRACE("full-size phantom, seed " + std::to_string(pp.seed) + ", voxel " + std::to_string(voxelMm) + " mm");
    const double truthVolumeMm3 = truth.lumenVolumeMl * 1000.0;

    MeshParams rawParams, halfParams;
    rawParams.smoothMethod = "none";
    halfParams.decimateFraction = 0.5;
    LumenSurfaceReport rawRep, rep, halfRep;
    const TriMesh raw = makeLumenSurface(*sdf, rawParams, &rawRep);
    const TriMesh mesh = makeLumenSurface(*sdf, MeshParams{}, &rep);
    const TriMesh half = makeLumenSurface(*sdf, halfParams, &halfRep);

    for (const LumenSurfaceReport* r : {&rawRep, &rep, &halfRep}) {
        SCOPED_TRACE(r == &rawRep ? "raw" : r == &rep ? "default (smoothed)" : "decimated to half");
        expectSoundPhantomSurface(*r);
        EXPECT_EQ(r->check.components, 1);
        EXPECT_EQ(r->check.genus, 0);
        EXPECT_TRUE(r->check.isClosed()) << "the phantom's colon lies inside the scan";
        EXPECT_NEAR(r->check.enclosedVolumeMm3 / truthVolumeMm3, 1.0, 0.02) << "within 2% of the mask volume";
    }
    // Smoothing: the volume moves by at most 1%.
    EXPECT_LT(std::fabs(rep.smoothingVolumeChange), 0.01);
    EXPECT_LT(rep.smoothedRoughnessDeg, rep.rawRoughnessDeg);
    // Decimation: half the faces, symmetric Hausdorff under half a voxel.
    EXPECT_TRUE(halfRep.decimation.reachedTarget);
    EXPECT_NEAR(double(halfRep.check.faces) / double(rep.check.faces), 0.5, 0.001);
    EXPECT_GT(halfRep.decimationHausdorffMm, 0.0);
    EXPECT_LT(halfRep.decimationHausdorffMm, 0.5 * voxelMm);

    // Every truth polyp still protrudes: height >= 90% of the truth, and within 10% of the
    // unsmoothed mesh's.
    ASSERT_FALSE(truth.polyps.empty());
    for (const PhantomPolyp& polyp : truth.polyps) {
        const test::PolypSite site = polypSite(truth, polyp);
        const double hRaw = test::polypHeightMm(raw, site), h = test::polypHeightMm(mesh, site),
                     hHalf = test::polypHeightMm(half, site);
        SCOPED_TRACE("polyp r=" + std::to_string(polyp.radiusMm) + " mm at arc " + std::to_string(polyp.arcMm) +
                     " mm: height raw " + std::to_string(hRaw) + ", smoothed " + std::to_string(h) + ", decimated " +
                     std::to_string(hHalf));
        EXPECT_GE(hRaw, 0.9 * polyp.radiusMm);
        EXPECT_GE(h, 0.9 * polyp.radiusMm);
        EXPECT_GE(hHalf, 0.9 * polyp.radiusMm);
        EXPECT_NEAR(h / hRaw, 1.0, 0.1);
        EXPECT_NEAR(hHalf / hRaw, 1.0, 0.1);
        std::cout << "[ measure  ] polyp r " << polyp.radiusMm << " mm: height raw " << hRaw << ", smoothed " << h
                  << ", decimated " << hHalf << " mm\n";
    }
    std::cout << "[ measure  ] faces raw " << rawRep.check.faces << ", smoothed " << rep.check.faces
              << ", decimated " << halfRep.check.faces << "; volume vs mask " << rep.check.enclosedVolumeMm3 / truthVolumeMm3 - 1
              << " (raw " << rawRep.check.enclosedVolumeMm3 / truthVolumeMm3 - 1 << ", decimated "
              << halfRep.check.enclosedVolumeMm3 / truthVolumeMm3 - 1 << "); smoothing volume change "
              << rep.smoothingVolumeChange << ", roughness " << rep.rawRoughnessDeg << " -> " << rep.smoothedRoughnessDeg
              << " deg, restored vertices " << rep.smoothingRestoredVertices << "; decimation Hausdorff "
              << halfRep.decimationHausdorffMm << " mm; "
              << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() << " s\n";
}

} // namespace
} // namespace flyover
