// view_bench: the interactive viewer's speed and memory, over loopback, against a real
// `flyover view` process.
//
//   view_bench --study DIR [--pairs N] [--px 512] [--launches 3]
//
// DIR is copied first (the server never writes into it here): centerline.json, surface.ply,
// ct.vdb, manifest.json, coverage/coverage.json. Then:
//   * time from launch to the URL line (median of --launches starts);
//   * request -> image time of N fly-over pairs (JPEG, px x px views) along the path, one
//     request in flight (as the page does): median, p95, and pairs/s sustained;
//   * the server's resident memory (VmRSS, VmHWM) against the scene's size (scene_bytes of
//     /api/study: vertices, normals, triangles, CT grid).
// Targets: median <= 25 ms, p95 <= 60 ms, >= 30 pairs/s, RSS <= scene + 300 MB,
// URL line <= 1 s.

#include <httplib.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <poll.h>
#include <regex>
#include <spawn.h>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

extern char** environ;

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace {

struct Server {
    pid_t pid = -1;
    int port = 0;
    std::string token;
    double urlSeconds = 0;
};

Server launch(const std::string& study)
{
    int out[2];
    if (::pipe(out) != 0) throw std::runtime_error("pipe failed");
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, out[1], 1);
    posix_spawn_file_actions_addclose(&actions, out[0]);
    std::vector<std::string> args = {FLYOVER_BIN, "view", "--study", study};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    Server s;
    const auto t0 = Clock::now();
    if (posix_spawn(&s.pid, FLYOVER_BIN, &actions, nullptr, argv.data(), environ) != 0)
        throw std::runtime_error(std::string("cannot start ") + FLYOVER_BIN);
    posix_spawn_file_actions_destroy(&actions);
    ::close(out[1]);
    std::string line;
    char ch;
    while (::read(out[0], &ch, 1) == 1 && ch != '\n') line += ch;
    s.urlSeconds = std::chrono::duration<double>(Clock::now() - t0).count();
    ::close(out[0]);
    std::smatch m;
    if (!std::regex_match(line, m, std::regex(R"(flyover: view: http://127\.0\.0\.1:(\d+)/\?token=([0-9a-f]+))")))
        throw std::runtime_error("no URL line from flyover view: '" + line + "'");
    s.port = std::stoi(m[1]);
    s.token = m[2];
    return s;
}

void stop(const Server& s)
{
    ::kill(s.pid, SIGTERM);
    int status = 0;
    ::waitpid(s.pid, &status, 0);
}

long statusKb(pid_t pid, const std::string& key)
{
    std::ifstream in("/proc/" + std::to_string(pid) + "/status");
    std::string line;
    while (std::getline(in, line))
        if (line.rfind(key + ":", 0) == 0) return std::stol(line.substr(key.size() + 1));
    return -1;
}

double percentile(std::vector<double> v, double p)
{
    std::sort(v.begin(), v.end());
    const std::size_t i = std::min(v.size() - 1, std::size_t(p * double(v.size() - 1) + 0.5));
    return v[i];
}

} // namespace

int main(int argc, char** argv)
{
    std::string study;
    int pairs = 300, px = 512, launches = 3;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) throw std::runtime_error(a + ": value missing");
            return argv[++i];
        };
        if (a == "--study") study = next();
        else if (a == "--pairs") pairs = std::stoi(next());
        else if (a == "--px") px = std::stoi(next());
        else if (a == "--launches") launches = std::stoi(next());
        else {
            std::cerr << "usage: view_bench --study DIR [--pairs N] [--px 512] [--launches 3]\n";
            return 2;
        }
    }
    if (study.empty() || pairs < 1 || px < 16 || launches < 1) {
        std::cerr << "usage: view_bench --study DIR [--pairs N] [--px 512] [--launches 3]\n";
        return 2;
    }
    // A copy: the benchmark never writes into the given study.
    const fs::path copy = fs::temp_directory_path() / ("flyover-view-bench-" + std::to_string(::getpid()));
    fs::create_directories(copy / "coverage");
    for (const char* f : {"centerline.json", "surface.ply", "ct.vdb", "manifest.json", "coverage/coverage.json"})
        if (fs::exists(fs::path(study) / f)) fs::copy_file(fs::path(study) / f, copy / f);

    std::vector<double> urlTimes;
    for (int k = 0; k + 1 < launches; ++k) {
        const Server s = launch(copy.string());
        urlTimes.push_back(s.urlSeconds);
        stop(s);
    }
    const Server s = launch(copy.string());
    urlTimes.push_back(s.urlSeconds);

    httplib::Client c("127.0.0.1", s.port);
    c.set_read_timeout(120, 0);
    c.set_keep_alive(true);
    c.set_default_headers({{"X-Flyover-Token", s.token}});
    const auto tLoad = Clock::now();
    auto info = c.Get("/api/study");
    if (!info || info->status != 200) throw std::runtime_error("/api/study failed");
    const double studySeconds = std::chrono::duration<double>(Clock::now() - tLoad).count();
    const json j = json::parse(info->body);
    const double arcMax = j["arc_max_mm"];
    // First pair (cold: frame radii of the first stretch), not counted.
    const auto tFirst = Clock::now();
    auto first = c.Get(("/api/pair?arc_mm=0&px=" + std::to_string(px)).c_str());
    if (!first || first->status != 200) throw std::runtime_error("/api/pair failed");
    const double firstSeconds = std::chrono::duration<double>(Clock::now() - tFirst).count();

    std::vector<double> ms;
    std::size_t bytes = 0;
    const double step = arcMax / double(pairs);
    const auto tRun = Clock::now();
    for (int k = 0; k < pairs; ++k) {
        const double arc = std::min(arcMax, (k + 1) * step);
        const auto t0 = Clock::now();
        auto r = c.Get(("/api/pair?arc_mm=" + std::to_string(arc) + "&px=" + std::to_string(px)).c_str());
        if (!r || r->status != 200) throw std::runtime_error("/api/pair failed at arc " + std::to_string(arc));
        ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        bytes += r->body.size();
    }
    const double runSeconds = std::chrono::duration<double>(Clock::now() - tRun).count();
    const long rssKb = statusKb(s.pid, "VmRSS"), hwmKb = statusKb(s.pid, "VmHWM");
    stop(s);
    fs::remove_all(copy);

    const double sceneMb = j.value("scene_bytes", 0.0) / 1048576.0;
    std::printf("study: %s (%.0f mm of path, %zu triangles)\n", study.c_str(), arcMax, j.value("triangles", std::size_t(0)));
    std::printf("URL line after launch: median %.3f s over %d launches (max %.3f s)\n", percentile(urlTimes, 0.5),
                launches, *std::max_element(urlTimes.begin(), urlTimes.end()));
    std::printf("/api/study (waits for the surface and CT to load): %.3f s after the URL; first pair %.1f ms\n",
                studySeconds, firstSeconds * 1e3);
    std::printf("pairs %d x (2 x %d px), JPEG, one in flight, along the path (step %.1f mm):\n", pairs, px, step);
    std::printf("  request -> image: median %.1f ms, p95 %.1f ms, max %.1f ms\n", percentile(ms, 0.5), percentile(ms, 0.95),
                *std::max_element(ms.begin(), ms.end()));
    std::printf("  sustained: %.1f pairs/s, %.0f kB per pair\n", double(pairs) / runSeconds, double(bytes) / pairs / 1024.0);
    std::printf("server memory: RSS %.0f MB, peak %.0f MB; scene (mesh + normals + CT grid) %.0f MB; RSS - scene %.0f MB\n",
                rssKb / 1024.0, hwmKb / 1024.0, sceneMb, rssKb / 1024.0 - sceneMb);
    return 0;
}
