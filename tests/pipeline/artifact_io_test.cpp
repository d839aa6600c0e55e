#include "pipeline/artifact_io.h"
#include "pipeline/deferred_writes.h"
#include "pipeline/grid_write.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <png.h>
#include <zlib.h>

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
            if (!noisy && w * h >= 1000) {
                EXPECT_LT(fs::file_size(path), img.rgb.size() / 4) << what << ": a smooth image is barely compressed";
            }

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

namespace {

void putU32(std::string& out, uint32_t v)
{
    for (int shift = 24; shift >= 0; shift -= 8) out.push_back(char(v >> shift));
}

void putChunk(std::string& out, const std::string& type, const std::string& data)
{
    putU32(out, uint32_t(data.size()));
    const std::string body = type + data;
    out += body;
    putU32(out, uint32_t(::crc32(0L, reinterpret_cast<const Bytef*>(body.data()), uInt(body.size()))));
}

/// A PNG written independently of the encoder under test: each row with a filter type drawn at
/// random (None, Sub, Up, Average, Paeth, by the PNG specification), zlib at `level`, the IDAT
/// data split into `idatChunks` chunks, with a tEXt chunk or another ancillary chunk as asked.
std::string handMadePng(const RgbImage& img, int colourType, std::mt19937& rng, int level, int idatChunks,
                        const std::string& extraChunk)
{
    const int bpp = colourType == 2 ? 3 : 1;
    const std::size_t rowBytes = std::size_t(img.width) * std::size_t(bpp);
    std::vector<uint8_t> px(rowBytes * std::size_t(img.height));
    for (std::size_t i = 0; i < px.size(); ++i) px[i] = bpp == 3 ? img.rgb[i] : img.rgb[3 * i];
    std::string raw;
    for (int y = 0; y < img.height; ++y) {
        const int type = int(rng() % 5);
        raw.push_back(char(type));
        const uint8_t* row = px.data() + std::size_t(y) * rowBytes;
        const uint8_t* up = y > 0 ? row - rowBytes : nullptr;
        for (std::size_t i = 0; i < rowBytes; ++i) {
            const int a = i >= std::size_t(bpp) ? row[i - std::size_t(bpp)] : 0, b = up ? up[i] : 0,
                      c = (up && i >= std::size_t(bpp)) ? up[i - std::size_t(bpp)] : 0;
            const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
            const int pred[5] = {0, a, b, (a + b) / 2, (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c)};
            raw.push_back(char(uint8_t(row[i] - pred[type])));
        }
    }
    std::string z(compressBound(uLong(raw.size())), '\0');
    uLongf zn = uLongf(z.size());
    EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(z.data()), &zn, reinterpret_cast<const Bytef*>(raw.data()),
                        uLong(raw.size()), level),
              Z_OK);
    z.resize(zn);
    std::string png("\x89PNG\r\n\x1a\n", 8), ihdr;
    putU32(ihdr, uint32_t(img.width));
    putU32(ihdr, uint32_t(img.height));
    ihdr += {8, char(colourType), 0, 0, 0};
    putChunk(png, "IHDR", ihdr);
    if (!extraChunk.empty()) putChunk(png, extraChunk, extraChunk == "gAMA" ? std::string("\0\0\xb1\x8f", 4) : "a\0b");
    const std::size_t part = z.size() / std::size_t(idatChunks) + 1;
    for (std::size_t at = 0; at < z.size(); at += part) putChunk(png, "IDAT", z.substr(at, part));
    putChunk(png, "IEND", "");
    return png;
}

/// libpng's simplified reader on bytes: the pixels as PNG_FORMAT_RGB, or "error: ...".
std::string libpngRgb(const std::string& bytes, RgbImage& out)
{
    png_image pi{};
    pi.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&pi, bytes.data(), bytes.size())) return std::string("error: ") + pi.message;
    pi.format = PNG_FORMAT_RGB;
    out.width = int(pi.width);
    out.height = int(pi.height);
    out.rgb.assign(PNG_IMAGE_SIZE(pi), 0);
    if (!png_image_finish_read(&pi, nullptr, out.rgb.data(), 0, nullptr)) return std::string("error: ") + pi.message;
    return "";
}

} // namespace

// readPng decodes plain 8-bit RGB files itself (ISA-L): every filter type, IDAT split in
// chunks, text chunks, stored and compressed streams give libpng's pixels; files it must not
// decode (gray, gamma) are declined and read by libpng with the same result.
TEST(ArtifactIo, PlainPngDecoderGivesLibpngsPixelsForEveryFilterAndDeclinesTheRest)
{
    std::mt19937 rng(11);
    const int sizes[][2] = {{1, 1}, {2, 3}, {5, 7}, {31, 9}, {130, 66}};
    int decoded = 0, declined = 0;
    for (const auto& wh : sizes)
        for (const int level : {0, 1, 9})
            for (const std::string extra : {"", "tEXt", "gAMA"})
                for (const int colourType : {2, 0}) {
                    RgbImage img;
                    img.width = wh[0];
                    img.height = wh[1];
                    img.rgb.resize(std::size_t(img.width) * std::size_t(img.height) * 3);
                    for (std::size_t i = 0; i < img.rgb.size(); ++i)
                        img.rgb[i] = (rng() % 3 == 0) ? uint8_t(rng()) : uint8_t(i * 7 / 5);
                    const std::string png = handMadePng(img, colourType, rng, level, 1 + int(rng() % 3), extra);
                    const std::string what = std::to_string(img.width) + " x " + std::to_string(img.height) +
                                             " level " + std::to_string(level) + " colour type " +
                                             std::to_string(colourType) + " " + extra;
                    RgbImage ref;
                    ASSERT_EQ(libpngRgb(png, ref), "") << what;
                    RgbImage fast;
                    const bool plain = colourType == 2 && extra != "gAMA";
                    EXPECT_EQ(decodePlainRgbPng(png, fast), plain) << what << ": expected the file to be "
                                                                   << (plain ? "decoded" : "declined");
                    if (plain) {
                        ++decoded;
                        EXPECT_EQ(fast.width, ref.width) << what;
                        EXPECT_EQ(fast.height, ref.height) << what;
                        EXPECT_TRUE(fast.rgb == ref.rgb) << what << ": pixels differ from libpng's";
                        EXPECT_TRUE(fast.rgb == img.rgb) << what << ": pixels differ from those written";
                    } else {
                        ++declined;
                    }
                }
    EXPECT_GT(decoded, 0);
    EXPECT_GT(declined, 0);
    // The frames' own encoder's files take the plain path.
    RgbImage frame;
    frame.width = 1028;
    frame.height = 512;
    frame.rgb.resize(std::size_t(1028) * 512 * 3);
    for (std::size_t i = 0; i < frame.rgb.size(); ++i) frame.rgb[i] = uint8_t((i / 3) % 1028 / 5 + (i % 3) * 40);
    RgbImage back;
    ASSERT_TRUE(decodePlainRgbPng(encodePng(frame), back)) << "encodePng's output was declined";
    EXPECT_TRUE(back.rgb == frame.rgb);
}

// A damaged plain PNG (bytes changed, cut short, garbage after IEND) gives readPng exactly
// libpng's answer: the same pixels, or a one-line InputError naming the file; never a crash.
TEST(ArtifactIo, DamagedPngReadsAsLibpngReadsIt)
{
    const fs::path d = tempDir("png-damaged");
    std::mt19937 rng(5);
    RgbImage img;
    img.width = 67;
    img.height = 41;
    img.rgb.resize(std::size_t(67) * 41 * 3);
    for (std::size_t i = 0; i < img.rgb.size(); ++i) img.rgb[i] = uint8_t(i % 67 + (i / 201) * 3);
    const std::string good = encodePng(img);
    int errors = 0, read = 0;
    for (int trial = 0; trial < 300; ++trial) {
        std::string bad = good;
        const int kind = trial % 3;
        if (kind == 0) {
            for (int k = 0, n = 1 + int(rng() % 4); k < n; ++k) bad[rng() % bad.size()] ^= char(1 + rng() % 255);
        } else if (kind == 1) {
            bad.resize(rng() % bad.size());
        } else {
            bad += std::string(1 + rng() % 20, char(rng()));
        }
        const std::string path = (d / "x.png").string();
        {
            std::ofstream out(path, std::ios::binary);
            out << bad;
        }
        RgbImage ref;
        const std::string refError = libpngRgb(bad, ref);
        try {
            const RgbImage got = readPng(path);
            EXPECT_EQ(refError, "") << "trial " << trial << ": readPng read a file libpng refuses";
            EXPECT_TRUE(got.rgb == ref.rgb && got.width == ref.width) << "trial " << trial << ": pixels differ from libpng's";
            ++read;
        } catch (const InputError& e) {
            EXPECT_NE(refError, "") << "trial " << trial << ": readPng refused a file libpng reads: " << e.what();
            const std::string msg = e.what();
            EXPECT_NE(msg.find(path), std::string::npos) << msg;
            EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
            ++errors;
        }
    }
    EXPECT_GT(errors, 100);
    EXPECT_GT(read, 20);
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
    EXPECT_FALSE(centerlineToJson(c).contains("left_out_branch")) << "written only when a branch was left out";

    // A left-out branch (the terminal ileum) reads back; a broken one is refused.
    c.leftOutBranchMm = {{1, 2, 3}, {1, 4, 3}, {1, 6, 2}};
    c.leftOutBranchRadiusMm = 11.0;
    nlohmann::json j = centerlineToJson(c);
    const Centerline withBranch = centerlineFromJson(j, "test");
    EXPECT_EQ(withBranch.leftOutBranchMm, c.leftOutBranchMm);
    EXPECT_EQ(withBranch.leftOutBranchRadiusMm, 11.0);
    j["left_out_branch"]["radius_mm"] = -1.0;
    EXPECT_THROW(centerlineFromJson(j, "bad.json"), InputError);
    j["left_out_branch"] = 3;
    EXPECT_THROW(centerlineFromJson(j, "bad.json"), InputError);
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
        writes.rename();
        EXPECT_EQ(readJson(a)["x"], 1);
        writes.sync();
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

TEST(ArtifactIo, VdbFilesHaveTheBytesOfOpenVdbsFileWriterButTheirUuid)
{
    // writeGrids writes through its own buffered stream, not io::File's: the bytes must be
    // io::File's (the seeked-back grid offsets included) but for the content-derived UUID.
    openvdb::initialize();
    const fs::path d = tempDir("vdb-bytes");
    auto hu = openvdb::FloatGrid::create(-1000.f);
    hu->setName("ct_hu");
    std::mt19937 random(7);
    std::uniform_real_distribution<float> value(-1000.f, 1500.f);
    for (int z = 0; z < 96; ++z)  // 96^3 voxels, 3.5 MB of values: the 1 MB buffer drains often
        for (int y = 0; y < 96; ++y)
            for (int x = 0; x < 96; ++x) hu->tree().setValue(openvdb::Coord(x, y, z), value(random));
    auto mask = openvdb::BoolGrid::create(false);
    mask->setName("lumen_mask");
    mask->tree().topologyUnion(hu->tree());
    for (const VdbValues values : {VdbValues::Raw, VdbValues::Blosc}) {
        const openvdb::GridPtrVec grids{hu, mask};
        writeGrids((d / "ours.vdb").string(), grids, values);
        openvdb::io::File file((d / "openvdb.vdb").string());
        file.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK |
                            (values == VdbValues::Raw ? 0u : uint32_t(openvdb::io::COMPRESS_BLOSC)));
        file.write(grids);
        file.close();
        std::string ours = fileBytes(d / "ours.vdb"), reference = fileBytes(d / "openvdb.vdb");
        const char* which = values == VdbValues::Raw ? "raw values" : "Blosc";
        ASSERT_GT(reference.size(), std::size_t(3) << 20) << which;
        ASSERT_EQ(ours.size(), reference.size()) << which;
        constexpr std::size_t UUID_OFFSET = 21, UUID_LENGTH = 36;
        ours.replace(UUID_OFFSET, UUID_LENGTH, reference, UUID_OFFSET, UUID_LENGTH);
        EXPECT_TRUE(ours == reference) << "writeGrids' bytes differ from io::File's beyond the UUID (" << which << ")";
        // The grid offsets it seeked back to write serve a delayed (random-access) read.
        auto back = openvdb::gridPtrCast<openvdb::FloatGrid>(readGridDelayed((d / "ours.vdb").string(), "ct_hu"));
        ASSERT_TRUE(back) << which;
        EXPECT_EQ(back->activeVoxelCount(), hu->activeVoxelCount()) << which;
        EXPECT_EQ(back->tree().getValue(openvdb::Coord(95, 40, 3)), hu->tree().getValue(openvdb::Coord(95, 40, 3)))
            << which;
    }
    fs::remove_all(d);
}

TEST(ArtifactIo, VdbWriteToAFolderThatIsGoneFailsCleanly)
{
    openvdb::initialize();
    const fs::path d = tempDir("vdb-gone");
    auto g = openvdb::FloatGrid::create(0.f);
    g->tree().setValue(openvdb::Coord(0, 0, 0), 1.f);
    EXPECT_THROW(writeGrids((d / "missing" / "a.vdb").string(), {g}, VdbValues::Raw), std::exception);
    EXPECT_FALSE(fs::exists(d / "missing"));
    fs::remove_all(d);
}

TEST(ArtifactIo, VdbWriteErrorsKeepTheirCause)
{
    // A full disk is retryable (writeAtomically maps ENOSPC to a TransientError): the buffered
    // writer must report the errno of the write that failed, not a bare "cannot write".
    openvdb::initialize();
    auto g = openvdb::FloatGrid::create(0.f);
    for (int x = 0; x < 200; ++x) g->tree().setValue(openvdb::Coord(x, 0, 0), float(x));
    try {
        writeVdbFile("/dev/full", {g}, VdbValues::Raw);
        FAIL() << "writing to /dev/full succeeded";
    } catch (const std::system_error& e) {
        EXPECT_EQ(e.code().value(), ENOSPC) << e.what();
    }
}
