#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace fs = std::filesystem;
using namespace flyover;

namespace {
fs::path tempDir(const std::string& name)
{
    fs::path d = fs::temp_directory_path() / ("flyover-test-" + name + "-" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}
} // namespace

TEST(ArtifactIo, PngRoundTripIsExact)
{
    const fs::path d = tempDir("png");
    RgbImage img;
    img.width = 7;
    img.height = 5;
    for (int i = 0; i < 7 * 5 * 3; ++i) img.rgb.push_back(static_cast<uint8_t>(i * 37 % 256));
    writePng((d / "a.png").string(), img);
    const RgbImage back = readPng((d / "a.png").string());
    EXPECT_EQ(back.width, 7);
    EXPECT_EQ(back.height, 5);
    EXPECT_EQ(back.rgb, img.rgb);
    fs::remove_all(d);
}

TEST(ArtifactIo, CenterlineJsonRoundTrip)
{
    Centerline c;
    c.stepMm = 1.0;
    for (int i = 0; i < 10; ++i) {
        CenterlinePoint p;
        p.positionMm = {double(i), 0.5 * i, -3.0};
        p.radiusMm = 10 + i;
        p.bridged = i == 4;
        c.points.push_back(p);
    }
    computeTangentsAndNormals(c);
    const Centerline back = centerlineFromJson(centerlineToJson(c), "test");
    ASSERT_EQ(back.points.size(), c.points.size());
    for (std::size_t i = 0; i < c.points.size(); ++i) {
        EXPECT_EQ(back.points[i].positionMm, c.points[i].positionMm);
        EXPECT_EQ(back.points[i].normal, c.points[i].normal);
        EXPECT_EQ(back.points[i].radiusMm, c.points[i].radiusMm);
        EXPECT_EQ(back.points[i].bridged, c.points[i].bridged);
    }
    EXPECT_THROW(centerlineFromJson(nlohmann::json{{"schema", "other"}}, "x.json"), InputError);
}

TEST(ArtifactIo, FailedAtomicWriteLeavesNothingBehind)
{
    const fs::path d = tempDir("atomic");
    const std::string target = (d / "out.json").string();
    writeJson(target, nlohmann::json{{"a", 1}});
    EXPECT_THROW(writeAtomically(target,
                                 [](const std::string& tmp) {
                                     std::ofstream(tmp) << "half a file";
                                     throw std::runtime_error("crash while writing");
                                 }),
                 std::runtime_error);
    // The old content survives and no temporary file is left.
    EXPECT_EQ(readJson(target)["a"], 1);
    int files = 0;
    for (const auto& e : fs::directory_iterator(d)) {
        ++files;
        EXPECT_EQ(e.path().filename(), "out.json");
    }
    EXPECT_EQ(files, 1);
    fs::remove_all(d);
}

TEST(ArtifactIo, DigestsDependOnContentOnly)
{
    const fs::path d = tempDir("digest");
    std::ofstream(d / "a") << "hello";
    std::ofstream(d / "b") << "hello";
    std::ofstream(d / "c") << "hellp";
    EXPECT_EQ(fileDigest((d / "a").string()), fileDigest((d / "b").string()));
    EXPECT_NE(fileDigest((d / "a").string()), fileDigest((d / "c").string()));
    EXPECT_EQ(fileDigest((d / "a").string()).size(), 32u);
    EXPECT_THROW(fileDigest((d / "missing").string()), InputError);
    fs::remove_all(d);
}

TEST(ArtifactIo, ReadJsonRejectsBrokenFiles)
{
    const fs::path d = tempDir("json");
    std::ofstream(d / "bad.json") << "{\"a\": ";
    try {
        readJson((d / "bad.json").string());
        FAIL() << "truncated JSON accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("bad.json"), std::string::npos) << e.what();
    }
    EXPECT_THROW(readJson((d / "none.json").string()), InputError);
    fs::remove_all(d);
}

TEST(ArtifactIo, VdbFilesAreByteIdenticalForIdenticalGrids)
{
    openvdb::initialize();
    const fs::path d = tempDir("vdb");
    auto g = openvdb::FloatGrid::create(-1000.f);
    g->setName("ct_hu");
    g->tree().setValue(openvdb::Coord(1, 2, 3), 40.f);
    writeGrids((d / "a.vdb").string(), {g});
    writeGrids((d / "b.vdb").string(), {g});
    EXPECT_EQ(fileDigest((d / "a.vdb").string()), fileDigest((d / "b.vdb").string()))
        << "OpenVDB's random file UUID must be replaced by a content-derived one";
    g->tree().setValue(openvdb::Coord(1, 2, 3), 41.f);
    writeGrids((d / "c.vdb").string(), {g});
    EXPECT_NE(fileDigest((d / "a.vdb").string()), fileDigest((d / "c.vdb").string()));
    auto back = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid((d / "a.vdb").string(), "ct_hu"));
    ASSERT_TRUE(back);
    EXPECT_EQ(back->tree().getValue(openvdb::Coord(1, 2, 3)), 40.f);
    EXPECT_THROW(readGrid((d / "a.vdb").string(), "nope"), InputError);
    fs::remove_all(d);
}

TEST(ArtifactIo, DeferredWritesStayInTheirTemporariesUntilFinished)
{
    const fs::path dir = tempDir("deferred");
    const std::string a = (dir / "a.json").string(), b = (dir / "b.json").string();
    auto tmpCount = [&] {
        int n = 0;
        for (const auto& e : fs::directory_iterator(dir)) n += e.path().filename().string().rfind(".tmp-", 0) == 0;
        return n;
    };
    {
        DeferredWrites writes;
        {
            const DeferredWrites::Scope scope(&writes);
            writeJson(a, nlohmann::json{{"x", 1}});
            EXPECT_FALSE(fs::exists(a)) << "a deferred write must not be visible under its name";
            const std::string pending = writtenFile(a);
            EXPECT_NE(pending, a);
            EXPECT_EQ(pending, writes.pendingFile(a));
            EXPECT_EQ(readJson(pending)["x"], 1) << "the temporary holds the whole content";
            {
                const DeferredWrites::Scope immediate(nullptr);  // a nested stage that writes at once
                writeJson(b, nlohmann::json{{"y", 2}});
                EXPECT_TRUE(fs::exists(b));
            }
            EXPECT_EQ(DeferredWrites::active(), &writes) << "the outer scope is back";
        }
        EXPECT_EQ(DeferredWrites::active(), nullptr);
        EXPECT_EQ(writtenFile(a), a) << "outside the scope the name is the file";
        EXPECT_EQ(tmpCount(), 1);
        writes.finish();
        EXPECT_EQ(readJson(a)["x"], 1);
        EXPECT_EQ(tmpCount(), 0);
    }
    {
        // A stage that fails before finish(): its temporaries go, its name keeps the old file.
        DeferredWrites writes;
        const DeferredWrites::Scope scope(&writes);
        writeJson(a, nlohmann::json{{"x", 3}});
    }
    EXPECT_EQ(tmpCount(), 0);
    EXPECT_EQ(readJson(a)["x"], 1);
    fs::remove_all(dir);
}
