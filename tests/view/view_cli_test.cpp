// `flyover view` as a program: what a study lacks is one line with the command that makes it;
// a running viewer prints its URL, serves with the token, and stops cleanly on SIGTERM/SIGINT.

#include "view_fixture.h"

#include <chrono>
#include <csignal>
#include <fcntl.h>
#include <poll.h>
#include <regex>
#include <spawn.h>
#include <sys/wait.h>

extern char** environ;

namespace fs = std::filesystem;
using nlohmann::json;
using namespace flyover;
using namespace flyover::test;

namespace {

struct Child {
    pid_t pid = -1;
    int out = -1;  ///< the child's stdout
    int err = -1;  ///< the child's stderr
};

Child spawnFlyover(const std::vector<std::string>& args)
{
    int outPipe[2], errPipe[2];
    if (::pipe(outPipe) != 0 || ::pipe(errPipe) != 0) return {};
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, outPipe[1], 1);
    posix_spawn_file_actions_adddup2(&actions, errPipe[1], 2);
    posix_spawn_file_actions_addclose(&actions, outPipe[0]);
    posix_spawn_file_actions_addclose(&actions, errPipe[0]);
    std::vector<std::string> all = {FLYOVER_BIN};
    all.insert(all.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& a : all) argv.push_back(a.data());
    argv.push_back(nullptr);
    Child c;
    if (posix_spawn(&c.pid, FLYOVER_BIN, &actions, nullptr, argv.data(), environ) != 0) c.pid = -1;
    posix_spawn_file_actions_destroy(&actions);
    ::close(outPipe[1]);
    ::close(errPipe[1]);
    c.out = outPipe[0];
    c.err = errPipe[0];
    return c;
}

/// Reads `fd` until a newline or the deadline. @return the line ("" on timeout or EOF).
std::string readLine(int fd, std::chrono::milliseconds timeout)
{
    std::string line;
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
        pollfd p{fd, POLLIN, 0};
        const int left = int(std::chrono::duration_cast<std::chrono::milliseconds>(end - std::chrono::steady_clock::now()).count());
        if (::poll(&p, 1, std::max(1, left)) <= 0) continue;
        char ch;
        const ssize_t n = ::read(fd, &ch, 1);
        if (n <= 0) break;
        if (ch == '\n') return line;
        line += ch;
    }
    return "";
}

std::string readAll(int fd)
{
    std::string s;
    char buf[4096];
    ssize_t n;
    while ((n = ::read(fd, buf, sizeof buf)) > 0) s.append(buf, std::size_t(n));
    return s;
}

/// Waits for the child; -1 when it has not exited within the timeout (it is then killed).
int waitExit(pid_t pid, std::chrono::seconds timeout)
{
    if (pid <= 0) return -1;  // never waitpid(-1): that would reap any child
    const auto end = std::chrono::steady_clock::now() + timeout;
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
        if (::waitpid(pid, &status, WNOHANG) == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    return -1;
}

struct CliResult {
    int code = -1;
    std::string out, err;
};

CliResult runToEnd(const std::vector<std::string>& args)
{
    Child c = spawnFlyover(args);
    CliResult r;
    r.out = readAll(c.out);
    r.err = readAll(c.err);
    r.code = waitExit(c.pid, std::chrono::seconds(60));
    ::close(c.out);
    ::close(c.err);
    return r;
}

int lines(const std::string& s) { return int(std::count(s.begin(), s.end(), '\n')); }

} // namespace

TEST(ViewCli, AStudyWithoutItsPartsSaysWhatIsMissingAndHowToMakeIt)
{
    const fs::path root = sharedStudy().root / "cli-missing";
    fs::create_directories(root / "empty");
    const CliResult empty = runToEnd({"view", "--study", (root / "empty").string()});
    EXPECT_EQ(empty.code, 1) << empty.err;
    EXPECT_EQ(lines(empty.err), 1) << empty.err;
    EXPECT_NE(empty.err.find("centerline.json"), std::string::npos) << empty.err;
    EXPECT_NE(empty.err.find("flyover run"), std::string::npos) << empty.err;
    EXPECT_TRUE(empty.out.empty()) << "no URL for a study that cannot be viewed: " << empty.out;

    // Only the surface missing: named, with the study's own input in the command.
    fs::create_directories(root / "nosurface");
    fs::copy_file(fs::path(sharedStudy().study) / "centerline.json", root / "nosurface" / "centerline.json");
    fs::copy_file(fs::path(sharedStudy().study) / "manifest.json", root / "nosurface" / "manifest.json");
    const CliResult noSurface = runToEnd({"view", "--study", (root / "nosurface").string()});
    EXPECT_EQ(noSurface.code, 1);
    EXPECT_EQ(lines(noSurface.err), 1) << noSurface.err;
    EXPECT_NE(noSurface.err.find("surface.ply"), std::string::npos) << noSurface.err;
    EXPECT_NE(noSurface.err.find("flyover run " + fs::absolute(sharedStudy().ctPath).string()), std::string::npos)
        << noSurface.err;

    const CliResult none = runToEnd({"view", "--study", (root / "does-not-exist").string()});
    EXPECT_EQ(none.code, 1);
    EXPECT_EQ(lines(none.err), 1) << none.err;

    // A corrupt surface: the URL may be out, then one line and exit 1.
    fs::create_directories(root / "corrupt");
    fs::copy_file(fs::path(sharedStudy().study) / "centerline.json", root / "corrupt" / "centerline.json");
    {
        // A header that promises more than the file holds, then a malformed header.
        std::ofstream(root / "corrupt" / "surface.ply")
            << "ply\nformat binary_little_endian 1.0\nelement vertex 99\nproperty float x\nproperty float y\n"
               "property float z\nelement face 5\nproperty list uchar int vertex_indices\nend_header\n0123";
    }
    const CliResult corrupt = runToEnd({"view", "--study", (root / "corrupt").string()});
    EXPECT_EQ(corrupt.code, 1) << corrupt.err;
    EXPECT_EQ(lines(corrupt.err), 1) << corrupt.err;
    EXPECT_NE(corrupt.err.find("surface.ply"), std::string::npos) << corrupt.err;

    fs::create_directories(root / "badheader");
    fs::copy_file(fs::path(sharedStudy().study) / "centerline.json", root / "badheader" / "centerline.json");
    std::ofstream(root / "badheader" / "surface.ply") << "ply\nformat binary_little_endian 1.0\nelement vertex 99\n";
    const CliResult badHeader = runToEnd({"view", "--study", (root / "badheader").string()});
    EXPECT_EQ(badHeader.code, 1) << badHeader.err;
    EXPECT_EQ(lines(badHeader.err), 1) << badHeader.err;
    EXPECT_NE(badHeader.err.find("surface.ply"), std::string::npos) << badHeader.err;

    const CliResult badPort = runToEnd({"view", "--study", sharedStudy().study, "--port", "70000"});
    EXPECT_EQ(badPort.code, 2) << badPort.err;
}

TEST(ViewCli, PrintsItsUrlServesAndStopsOnSignals)
{
    for (const int sig : {SIGTERM, SIGINT}) {
        const auto t0 = std::chrono::steady_clock::now();
        Child c = spawnFlyover({"view", "--study", sharedStudy().study});
        ASSERT_GT(c.pid, 0);
        const std::string line = readLine(c.out, std::chrono::seconds(30));
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::smatch m;
        ASSERT_TRUE(std::regex_match(line, m, std::regex(R"(flyover: view: http://127\.0\.0\.1:(\d+)/\?token=([0-9a-f]{64}))")))
            << "the URL line: '" << line << "'";
        std::cout << "URL line after " << seconds << " s\n";
        const int port = std::stoi(m[1]);
        httplib::Client client("127.0.0.1", port);
        client.set_read_timeout(60, 0);
        auto study = client.Get(("/api/study?token=" + m[2].str()).c_str());
        ASSERT_TRUE(study);
        EXPECT_EQ(study->status, 200);
        auto pair = client.Get(("/api/pair?arc_mm=30&px=64&token=" + m[2].str()).c_str());
        ASSERT_TRUE(pair);
        EXPECT_EQ(pair->status, 200);
        EXPECT_EQ(client.Get("/api/study")->status, 403);
        ::kill(c.pid, sig);
        EXPECT_EQ(waitExit(c.pid, std::chrono::seconds(20)), 0) << "signal " << sig << ": " << readAll(c.err);
        ::close(c.out);
        ::close(c.err);
        // The port is free again.
        httplib::Client after("127.0.0.1", port);
        after.set_connection_timeout(1, 0);
        EXPECT_FALSE(after.Get("/api/study"));
    }
}
