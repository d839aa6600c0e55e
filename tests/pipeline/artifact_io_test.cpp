#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <png.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

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

// The frames' own PNG encoder (Up filter, ISA-L deflate): libpng reads back the same pixels
// for images of many sizes, noisy (stored blocks) and smooth (compressed), RGB and gray.
TEST(ArtifactIo, PngOfManySizesAndContentsReadsBackExactlyThroughLibpng)
{
    const fs::path d = tempDir("png-sizes");
    std::mt19937 rng(7);
    const int sizes[][2] = {{1, 1}, {2, 3}, {7, 5}, {33, 17}, {257, 129}, {1028, 512}};
    for (const auto& wh : sizes)
        for (const bool noisy : {false, true}) {
            const int w = wh[0], h = wh[1];
            RgbImage img;
            img.width = w;
            img.height = h;
            img.rgb.resize(std::size_t(w) * std::size_t(h) * 3);
            std::vector<uint8_t> gray(std::size_t(w) * std::size_t(h));
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    const std::size_t i = std::size_t(y) * std::size_t(w) + std::size_t(x);
                    for (int c = 0; c < 3; ++c)
                        img.rgb[3 * i + std::size_t(c)] =
                            noisy ? uint8_t(rng() & 0xff) : uint8_t((x * (c + 1) + y * 3 + (x * y) / 64) & 0xff);
                    gray[i] = noisy ? uint8_t(rng() & 0xff) : uint8_t((x + 2 * y) & 0xff);
                }
            const std::string what = std::to_string(w) + " x " + std::to_string(h) + (noisy ? " noise" : " smooth");
            const std::string path = (d / "a.png").string();
            writePng(path, img);
            const RgbImage back = readPng(path);
            ASSERT_EQ(back.width, w) << what;
            ASSERT_EQ(back.height, h) << what;
            EXPECT_TRUE(back.rgb == img.rgb) << what << ": the pixels read back differ from those written";
            if (!noisy && w * h >= 1000)
                EXPECT_LT(fs::file_size(path), img.rgb.size() / 4) << what << ": a smooth image is barely compressed";

            const std::string grayPng = encodeGrayPng(w, h, gray);
            png_image pi{};
            pi.version = PNG_IMAGE_VERSION;
            ASSERT_TRUE(png_image_begin_read_from_memory(&pi, grayPng.data(), grayPng.size())) << what << ": " << pi.message;
            pi.format = PNG_FORMAT_GRAY;
            std::vector<uint8_t> grayBack(PNG_IMAGE_SIZE(pi));
            ASSERT_TRUE(png_image_finish_read(&pi, nullptr, grayBack.data(), 0, nullptr)) << what << ": " << pi.message;
            EXPECT_TRUE(grayBack == gray) << what << ": the gray pixels read back differ from those encoded";
        }
    EXPECT_THROW(encodeGrayPng(4, 4, std::vector<uint8_t>(15)), InputError);
    RgbImage wrong;
    wrong.width = 3;
    wrong.height = 2;
    wrong.rgb.resize(17);
    EXPECT_THROW(writePng((d / "b.png").string(), wrong), InputError);
    EXPECT_FALSE(fs::exists(d / "b.png"));
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

namespace {
std::string fileBytes(const fs::path& p)
{
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

/// A wavy open sheet of n x n quads split into triangles (boundary, valences 3-6), its
/// coordinates irregular in their low bits.
TriMesh wavySheet(int n)
{
    TriMesh mesh;
    std::vector<TriMesh::VertexHandle> v;
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i)
            v.push_back(mesh.add_vertex(TriMesh::Point(0.37f * float(i), 0.41f * float(j),
                                                       std::sin(0.3f * float(i * j)) + 1e-3f * float(i))));
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const auto a = v[std::size_t(j * (n + 1) + i)], b = v[std::size_t(j * (n + 1) + i + 1)];
            const auto c = v[std::size_t((j + 1) * (n + 1) + i)], d = v[std::size_t((j + 1) * (n + 1) + i + 1)];
            if ((i + j) % 2) {
                mesh.add_face(a, b, d);
                mesh.add_face(a, d, c);
            } else {
                mesh.add_face(a, b, c);
                mesh.add_face(b, d, c);
            }
        }
    return mesh;
}
} // namespace

TEST(ArtifactIo, MeshFilesHaveTheBytesOfOpenMeshsPlyWriter)
{
    const fs::path d = tempDir("ply");
    const TriMesh sheet = wavySheet(23);
    TriMesh mesh = sheet;
    // Faces deleted and collected: the face-vertex circulation starts at other halfedges.
    mesh.request_face_status();
    mesh.request_edge_status();
    mesh.request_vertex_status();
    for (int f = 0; f < int(mesh.n_faces()); f += 7) mesh.delete_face(OpenMesh::FaceHandle(f), true);
    mesh.garbage_collection();
    for (const TriMesh* m : {&sheet, static_cast<const TriMesh*>(&mesh)}) {
        writeMesh((d / "fast.ply").string(), *m);
        writeMeshWithOpenMesh((d / "openmesh.ply").string(), *m);
        const std::string fast = fileBytes(d / "fast.ply"), reference = fileBytes(d / "openmesh.ply");
        const char* which = m == &sheet ? "sheet" : "sheet with faces deleted and collected";
        ASSERT_GT(reference.size(), 1000u) << which;
        EXPECT_EQ(fast.size(), reference.size()) << which;
        EXPECT_TRUE(fast == reference) << "writeMesh's PLY differs from OpenMesh's bytes (" << which << ")";
    }
    writeMesh((d / "fast.ply").string(), mesh);
    const TriMesh back = readMesh((d / "fast.ply").string());
    EXPECT_EQ(back.n_faces(), mesh.n_faces());
    EXPECT_EQ(back.n_vertices(), mesh.n_vertices());
    fs::remove_all(d);
}
