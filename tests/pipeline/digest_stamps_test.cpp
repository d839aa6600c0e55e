// Digest stamps (pipeline/digest_stamps.h): a file's digest is taken from its stamp only while
// the file has not been written since; any write — in place with its old modification time
// restored, or by replacement — makes it hashed again (an unchanged re-run stays fast yet safe).

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/digest_stamps.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <thread>

namespace fs = std::filesystem;
using namespace flyover;

namespace {

class DigestStampsTest : public ::testing::Test {
protected:
    void SetUp() override
    {
        mDir = fs::temp_directory_path() / ("flyover-stamps-" + std::to_string(::getpid()));
        fs::remove_all(mDir);
        fs::create_directories(mDir);
    }
    void TearDown() override { fs::remove_all(mDir); }

    std::string file(const std::string& name) const { return (mDir / name).string(); }
    std::string stampsFile() const { return file("stamps.json"); }

    static void write(const std::string& path, const std::string& text)
    {
        std::ofstream out(path, std::ios::binary | std::ios::trunc);
        out << text;
    }

    /// A stamps file that says `path` holds `digest` (as a run that hashed it would leave).
    void stampAs(const std::string& path, const std::string& digest) const
    {
        DigestStamps s(stampsFile());
        s.hashed(path, digest);
        s.save();
    }

    fs::path mDir;
};

} // namespace

TEST_F(DigestStampsTest, UnchangedFileTakesItsStampedDigest)
{
    const std::string f = file("a.bin");
    write(f, "0123456789");
    stampAs(f, "stamped-digest");
    DigestStamps s(stampsFile());
    EXPECT_EQ(s.digest(f), "stamped-digest") << "an unchanged file should not be hashed again";
}

TEST_F(DigestStampsTest, InPlaceWriteWithRestoredMtimeIsHashedAgain)
{
    const std::string f = file("a.bin");
    write(f, "0123456789");
    struct stat before{};
    ASSERT_EQ(::stat(f.c_str(), &before), 0);
    stampAs(f, fileDigest(f));
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    {
        // Same size, same inode, and the old modification time put back.
        std::fstream io(f, std::ios::binary | std::ios::in | std::ios::out);
        io.seekp(3);
        io << 'X';
    }
    const timespec times[2] = {before.st_atim, before.st_mtim};
    ASSERT_EQ(::utimensat(AT_FDCWD, f.c_str(), times, 0), 0);
    DigestStamps s(stampsFile());
    EXPECT_EQ(s.digest(f), fileDigest(f)) << "the edited file kept its size, inode and mtime; its status-change "
                                             "time moved, so it must be hashed again";
}

TEST_F(DigestStampsTest, ReplacedFileIsHashedAgain)
{
    const std::string f = file("a.bin"), g = file("b.bin");
    write(f, "0123456789");
    stampAs(f, "stamped-digest");
    write(g, "abcdefghij");
    fs::rename(g, f);
    DigestStamps s(stampsFile());
    EXPECT_EQ(s.digest(f), fileDigest(f));
}

TEST_F(DigestStampsTest, DamagedStampsFileMeansHashEverything)
{
    const std::string f = file("a.bin");
    write(f, "0123456789");
    stampAs(f, "stamped-digest");
    write(stampsFile(), "{\"schema\": \"flyover.stamps/1\", \"files\": {\"" + f + "\": {\"dev\": ");
    DigestStamps s(stampsFile());
    EXPECT_EQ(s.digest(f), fileDigest(f));
}

TEST_F(DigestStampsTest, FolderDigestIsArtifactDigest)
{
    const fs::path d = mDir / "frames";
    fs::create_directories(d);
    write((d / "pair_0000.png").string(), "one");
    write((d / "pair_0001.png").string(), "two");
    DigestStamps s(stampsFile());
    EXPECT_EQ(s.digest(d.string()), artifactDigest(d.string()));
    s.save();  // stamps both files, as hashed
    DigestStamps again(stampsFile());
    EXPECT_EQ(again.digest(d.string()), artifactDigest(d.string()));
}
