// Export through OpenMesh's writers and back through its readers, in every format.
#include "surface/mesh_export.h"

#include "surface/extract_surface.h"
#include "surface/mesh_checks.h"
#include "volume/error.h"

#include <openvdb/tools/LevelSetSphere.h>

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace fs = std::filesystem;

namespace flyover {
namespace {

class MeshExport : public ::testing::Test {
protected:
    void SetUp() override
    {
        mDir = fs::temp_directory_path() / ("flyover-mesh-export-" + std::to_string(::getpid()));
        fs::create_directories(mDir);
        auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(6.f, openvdb::Vec3f(0.3f), 0.5f, 3.f);
        mMesh = extractSurface(*grid, MeshParams{});
    }
    void TearDown() override { fs::remove_all(mDir); }

    std::string path(const std::string& name) const { return (mDir / name).string(); }

    fs::path mDir;
    TriMesh mMesh;
};

std::string head(const std::string& path, std::size_t n)
{
    std::ifstream in(path, std::ios::binary);
    std::string s(n, '\0');
    in.read(&s[0], std::streamsize(n));
    s.resize(std::size_t(in.gcount()));
    return s;
}

TEST_F(MeshExport, EveryFormatReadsBackAsTheSameSurface)
{
    const MeshCheck original = checkMesh(mMesh);
    for (const std::string ext : {".ply", ".obj", ".stl", ".off"}) {
        SCOPED_TRACE("format " + ext);
        const std::string file = path("surface" + ext);
        ASSERT_NO_THROW(writeMeshFile(mMesh, file));
        const TriMesh back = readMeshFile(file);
        EXPECT_EQ(back.n_faces(), mMesh.n_faces());
        // STL keeps no shared vertices; the reader merges corners by position.
        EXPECT_EQ(back.n_vertices(), mMesh.n_vertices());
        const MeshCheck c = checkMesh(back);
        EXPECT_EQ(c.genus, 0);
        EXPECT_EQ(c.boundaryEdges, 0);
        EXPECT_EQ(c.misorientedComponents, 0);  // the winding survives
        // Binary floats are exact; OBJ's text has ~7 significant digits.
        EXPECT_NEAR(c.enclosedVolumeMm3 / original.enclosedVolumeMm3, 1.0, 1e-5);
        EXPECT_NEAR(c.areaMm2 / original.areaMm2, 1.0, 1e-5);
    }
}

TEST_F(MeshExport, BinaryWhereTheFormatAllows)
{
    writeMeshFile(mMesh, path("s.ply"));
    EXPECT_NE(head(path("s.ply"), 200).find("format binary_little_endian"), std::string::npos);
    writeMeshFile(mMesh, path("s.off"));
    EXPECT_EQ(head(path("s.off"), 10).rfind("OFF BINARY", 0), 0u) << head(path("s.off"), 10);
    writeMeshFile(mMesh, path("s.stl"));
    // Binary STL: 80-byte header, 32-bit count, 50 bytes per triangle.
    EXPECT_EQ(fs::file_size(path("s.stl")), 84u + 50u * mMesh.n_faces());
    writeMeshFile(mMesh, path("s.obj"));
    const std::string obj = head(path("s.obj"), 4096);
    EXPECT_NE(obj.find("\nv "), std::string::npos);
    EXPECT_TRUE(isBinaryMeshFormat(".stl"));
    EXPECT_FALSE(isBinaryMeshFormat(".obj"));
    EXPECT_FALSE(isMeshFileFormat(".vtk"));
}

TEST_F(MeshExport, WritersAndReadersAreQuiet)
{
    ::testing::internal::CaptureStderr();
    ::testing::internal::CaptureStdout();
    for (const std::string ext : {".ply", ".obj", ".stl", ".off"}) {
        writeMeshFile(mMesh, path("quiet" + ext));
        readMeshFile(path("quiet" + ext));
    }
    const std::string err = ::testing::internal::GetCapturedStderr();
    const std::string out = ::testing::internal::GetCapturedStdout();
    EXPECT_EQ(err, "");
    EXPECT_EQ(out, "");
}

TEST_F(MeshExport, BadPathsAreInputErrors)
{
    EXPECT_THROW(writeMeshFile(mMesh, path("surface.vtk")), InputError);
    EXPECT_THROW(writeMeshFile(mMesh, path("no/such/folder/surface.ply")), InputError);
    EXPECT_THROW(readMeshFile(path("missing.ply")), InputError);
    try {
        writeMeshFile(mMesh, path("surface.vtk"));
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("surface.vtk"), std::string::npos) << e.what();
    }
}

} // namespace
} // namespace flyover
