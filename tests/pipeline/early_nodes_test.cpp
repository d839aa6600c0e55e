// The early nodes of the stage graph (colon/stage_early.cpp): the segmentation made beside
// ingest's write of ct.vdb is the segment stage's own; the mesh and the centerline made beside
// the segment stage's contact cut (colon/uncut_lumen.h) are those of the lumen the segment stage
// hands on: kept when the cut removes nothing, dropped when it cuts.

#include "colon/phantom.h"
#include "pipeline/artifact_io.h"
#include "colon/phantom_io.h"
#include "colon/uncut_lumen.h"
#include "colon/study_run.h"
#include "surface/lumen_surface.h"
#include "tests/pipeline/study_fixture.h"

#include <gtest/gtest.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <tbb/global_control.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <stdexcept>
#include <thread>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

/// The small phantom (seed 1) with two touching loops, written as ROOT/NAME.nii.gz with its
/// truth beside it: the segment stage cuts both contacts.
std::string writeTouchingPhantom(const fs::path& root, const std::string& name)
{
    PhantomParams pp;
    pp.size = PhantomSize::Small;
    pp.seed = 1;
    pp.touching = 2;
    const std::string ct = (root / (name + ".nii.gz")).string();
    writePhantom(makePhantom(pp), pp, ct, (root / (name + ".json")).string(), "");
    return ct;
}

nlohmann::json stageEntry(const nlohmann::json& manifest, const std::string& stage)
{
    for (const auto& e : manifest["stages"])
        if (e["stage"] == stage) return e;
    ADD_FAILURE() << "no " << stage << " entry in the manifest";
    return nlohmann::json::object();
}

/// The mesh of one run through the mesh stage, and of the mesh stage run in a second call from
/// the lumen.vdb of a first that stopped after segment (no mesh beside the cut there).
void expectSameMeshEitherWay(RunOptions one, RunOptions two, bool besideExpected, int cutExpected)
{
    one.untilStage = "mesh";
    const nlohmann::json a = runPipeline(one);
    const nlohmann::json segA = stageEntry(a, "segment"), meshA = stageEntry(a, "mesh");
    EXPECT_EQ(segA["report"]["contacts"]["cut"].get<int>(), cutExpected);
    EXPECT_TRUE(meshA["computed"].get<bool>());
    EXPECT_EQ(meshA["report"]["made_beside_contact_cut"].get<bool>(), besideExpected)
        << "contacts cut: " << segA["report"]["contacts"]["cut"];
    // The final checks are made behind the next stages; the manifest and the cache record
    // hold them all the same (a re-run takes the report from the record).
    EXPECT_TRUE(meshA["report"]["checked_behind"].get<bool>());
    EXPECT_GT(meshA["report"]["faces"].get<int64_t>(), 0) << "the report left without its checks";
    {
        // The figures of the checks made at once on the study's lumen level set.
        const auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(one.studyDir + "/lumen.vdb", "lumen_sdf"));
        LumenSurfaceReport now;
        makeLumenSurface(*sdf, one.params.mesh, &now);
        EXPECT_EQ(meshA["report"]["faces"].get<int64_t>(), now.check.faces);
        EXPECT_EQ(meshA["report"]["genus"].get<int64_t>(), now.check.genus);
        EXPECT_EQ(meshA["report"]["outward_faces"].get<int64_t>(), now.orientation.outward);
        EXPECT_EQ(meshA["report"]["non_manifold_vertices"].get<int64_t>(), now.check.nonManifoldVertices);
        EXPECT_EQ(meshA["report"]["sound"].get<bool>(), now.isSound());
    }
    const nlohmann::json again = stageEntry(runPipeline(one), "mesh");
    EXPECT_FALSE(again["computed"].get<bool>());
    EXPECT_EQ(again["report"], meshA["report"]) << "the cache record's report is not the manifest's";

    two.untilStage = "segment";
    runPipeline(two);
    two.untilStage = "mesh";
    const nlohmann::json b = runPipeline(two);
    const nlohmann::json meshB = stageEntry(b, "mesh");
    EXPECT_TRUE(meshB["computed"].get<bool>());
    EXPECT_FALSE(meshB["report"]["made_beside_contact_cut"].get<bool>());
    EXPECT_EQ(stageEntry(b, "segment")["outputs"], segA["outputs"]) << "the same lumen.vdb";
    EXPECT_EQ(meshB["outputs"], meshA["outputs"]) << "surface.ply differs between the mesh made beside the "
                                                     "contact cut and the mesh stage's own";
    EXPECT_EQ(meshB["report"]["faces"], meshA["report"]["faces"]);
    for (const char* field : {"genus", "components", "boundary_loops", "outward_faces", "sound"})
        EXPECT_EQ(meshB["report"][field], meshA["report"][field]) << field;
    // A parallel sum: equal to the last bits only.
    const double areaA = meshA["report"]["area_mm2"].get<double>();
    EXPECT_NEAR(meshB["report"]["area_mm2"].get<double>(), areaA, 1e-9 * areaA);
    EXPECT_EQ(meshB["key"], meshA["key"]);
}

/// The centerline of one run through the centerline stage, and of the centerline stage run in
/// a second call from the lumen.vdb of a first that stopped after segment (nothing traced
/// beside the cut there): the same centerline.json, the same report but for where it was traced.
void expectSameCenterlineEitherWay(RunOptions one, RunOptions two, bool besideExpected, int cutExpected)
{
    one.untilStage = "centerline";
    const nlohmann::json a = runPipeline(one);
    const nlohmann::json segA = stageEntry(a, "segment"), clA = stageEntry(a, "centerline");
    EXPECT_EQ(segA["report"]["contacts"]["cut"].get<int>(), cutExpected);
    EXPECT_TRUE(clA["computed"].get<bool>());
    EXPECT_EQ(clA["report"]["traced_beside_contact_cut"].get<bool>(), besideExpected)
        << "contacts cut: " << segA["report"]["contacts"]["cut"];
    // The pieces the path runs through, in travel order, each with where its route was found.
    const nlohmann::json& pieces = clA["report"]["pieces"];
    ASSERT_TRUE(pieces.is_array() && !pieces.empty()) << clA["report"].dump();
    EXPECT_EQ(pieces.size(), clA["report"]["bridges"].size() + 1) << "a bridge between consecutive pieces";
    for (const nlohmann::json& p : pieces) {
        ASSERT_TRUE(p.is_object()) << pieces.dump();
        const std::string on = p["route_searched_on"].get<std::string>();
        EXPECT_TRUE(on == "coarse core" || on == "core" || on == "core and corridors" || on == "whole piece") << on;
        EXPECT_GT(p["path_length_mm"].get<double>(), 0.0);
        EXPECT_GT(p["volume_ml"].get<double>(), 0.0);
    }

    two.untilStage = "segment";
    runPipeline(two);
    two.untilStage = "centerline";
    const nlohmann::json clB = stageEntry(runPipeline(two), "centerline");
    EXPECT_TRUE(clB["computed"].get<bool>());
    EXPECT_FALSE(clB["report"]["traced_beside_contact_cut"].get<bool>());
    EXPECT_EQ(clB["outputs"], clA["outputs"]) << "centerline.json differs between the centerline traced beside "
                                                 "the contact cut and the centerline stage's own";
    nlohmann::json reportA = clA["report"], reportB = clB["report"];
    reportA.erase("traced_beside_contact_cut");
    reportB.erase("traced_beside_contact_cut");
    EXPECT_EQ(reportB, reportA) << "the centerline reports differ";
    EXPECT_EQ(clB["key"], clA["key"]);
}

} // namespace

TEST_F(StudyTest, SegmentationBegunBesideCtWriteIsTheSegmentStagesOwn)
{
    // One run through segment (segmentLumen begun beside ct.vdb's write), and one that stops
    // after ingest and segments in a second call (from ct.vdb): the same lumen.vdb and report.
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
    RunOptions one = options("seg-beside-one"), two = options("seg-beside-two");
    one.untilStage = "segment";
    const nlohmann::json segA = stageEntry(runPipeline(one), "segment");
    EXPECT_TRUE(segA["computed"].get<bool>());
    EXPECT_TRUE(segA["report"]["segmented_beside_ct_write"].get<bool>());
    two.untilStage = "ingest";
    runPipeline(two);
    two.untilStage = "segment";
    const nlohmann::json segB = stageEntry(runPipeline(two), "segment");
    EXPECT_TRUE(segB["computed"].get<bool>());
    EXPECT_FALSE(segB["report"]["segmented_beside_ct_write"].get<bool>());
    EXPECT_EQ(segB["outputs"], segA["outputs"]) << "lumen.vdb differs between the segmentation begun beside "
                                                   "ct.vdb's write and the segment stage's own";
    EXPECT_EQ(segB["key"], segA["key"]);
    nlohmann::json reportA = segA["report"], reportB = segB["report"];
    reportA.erase("segmented_beside_ct_write");
    reportB.erase("segmented_beside_ct_write");
    EXPECT_EQ(reportB, reportA) << "the segment reports differ";

    // Ingest recomputed (its record gone) to the same ct.vdb: the segment stage is reused, and
    // the segmentation made beside the write is left unused.
    for (const auto& e : fs::directory_iterator(fs::path(one.studyDir) / ".flyover" / "records"))
        if (e.path().filename().string().rfind("ingest-", 0) == 0) fs::remove(e.path());
    const nlohmann::json again = runPipeline(one);
    EXPECT_TRUE(stageEntry(again, "ingest")["computed"].get<bool>());
    EXPECT_FALSE(stageEntry(again, "segment")["computed"].get<bool>()) << "the same ct.vdb: segment is reused";
    EXPECT_EQ(stageEntry(again, "segment")["outputs"], segA["outputs"]);
}

TEST_F(StudyTest, CenterlineBesideAContactCutThatRemovesNothingIsKept)
{
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
    expectSameCenterlineEitherWay(options("cl-beside-one"), options("cl-beside-two"), true, 0);
}

TEST_F(StudyTest, CenterlineBesideAContactCutThatCutsIsDropped)
{
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
    const std::string ct = writeTouchingPhantom(sRoot, "cl-touching");
    RunOptions one = options("cl-cut-one"), two = options("cl-cut-two");
    one.ctPath = two.ctPath = ct;
    expectSameCenterlineEitherWay(one, two, false, 2);
}

TEST_F(StudyTest, MeshBesideAContactCutThatRemovesNothingIsKept)
{
    // Two threads at least (with one, nothing is meshed beside the cut), whatever the machine.
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
    expectSameMeshEitherWay(options("beside-one"), options("beside-two"), true, 0);
}

TEST_F(StudyTest, MeshBesideAContactCutThatCutsIsDropped)
{
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
    const std::string ct = writeTouchingPhantom(sRoot, "touching");
    RunOptions one = options("cut-one"), two = options("cut-two");
    one.ctPath = two.ctPath = ct;
    expectSameMeshEitherWay(one, two, false, 2);
}

// An uncut lumen superseded by the cut stops its early mesh at its first progress report, and
// the last of its readers frees the copy; not superseded, the early mesh is makeLumenSurface's.
TEST(UncutLumen, SupersededWorkStopsAndTheLastReaderFreesTheCopy)
{
    const openvdb::FloatGrid::ConstPtr sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        20.0f, openvdb::Vec3f(0.0f), 0.8f);
    RunOptions options;
    options.studyDir = (fs::temp_directory_path() / "flyover-uncut-lumen-test").string();
    StudyRun run(options);

    run.state.uncutLumen = std::make_shared<UncutLumen>(sphere, 2);
    run.state.uncutLumen->superseded = true;
    EXPECT_EQ(sphere.use_count(), 2);
    EXPECT_THROW(meshUncutLumen(run, nullptr), Cancelled);
    EXPECT_FALSE(run.state.uncutLumen->mesh.has_value());
    EXPECT_EQ(sphere.use_count(), 2) << "freed while a reader was left";
    run.state.uncutLumen->doneReading();
    EXPECT_EQ(sphere.use_count(), 1) << "the last reader did not free the copy";

    run.state.uncutLumen = std::make_shared<UncutLumen>(sphere, 1);
    meshUncutLumen(run, nullptr);
    ASSERT_TRUE(run.state.uncutLumen->mesh.has_value());
    EXPECT_EQ(sphere.use_count(), 1);
    LumenSurfaceReport plainReport;
    const TriMesh plain = makeLumenSurface(*sphere, options.params.mesh, &plainReport, nullptr, true, true);
    const TriMesh& early = *run.state.uncutLumen->mesh;
    ASSERT_GT(plain.n_faces(), 0u);
    ASSERT_EQ(early.n_vertices(), plain.n_vertices());
    EXPECT_EQ(early.n_faces(), plain.n_faces());
    for (const auto v : plain.vertices()) ASSERT_EQ(early.point(v), plain.point(v)) << "vertex " << v.idx();
}
