/// @file render_output.h
/// @brief What the render steps of `flyover run` and `flyover inspect` share to write their
///        outputs (internal to pipeline/): folders written under a temporary name and renamed
///        into place, the ffmpeg encoder fed raw frames, the cameras' JSON.
#pragma once

#include "render/camera.h"
#include "render/render_view.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>

#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <spawn.h>
#include <stdexcept>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

extern char** environ;

namespace flyover {

namespace fs = std::filesystem;

inline nlohmann::json cameraJson(const Camera& c)
{
    auto v = [](const Vec3d& x) { return nlohmann::json::array({x.x, x.y, x.z}); };
    return nlohmann::json{{"position_mm", v(c.position)}, {"forward", v(c.forward)},
                          {"up", v(c.up)},                {"right", v(c.right)},
                          {"fov_deg", c.fovDeg},          {"near_mm", c.nearMm}};
}

/// A folder written under a temporary name that replaces `dir/name` only on commit(); removed
/// if never committed (an exception on the way), so a half-written folder is never trusted.
class StagedFolder {
public:
    StagedFolder(const fs::path& dir, const std::string& name)
        : mTarget(dir / name), mTmp(dir / (".tmp-" + std::to_string(::getpid()) + "-" + name))
    {
        fs::remove_all(mTmp);
        fs::create_directories(mTmp);
    }
    ~StagedFolder()
    {
        std::error_code ec;
        if (!mCommitted) fs::remove_all(mTmp, ec);
    }
    StagedFolder(const StagedFolder&) = delete;
    StagedFolder& operator=(const StagedFolder&) = delete;

    std::string path(const std::string& file) const { return (mTmp / file).string(); }

    void commit()
    {
        const fs::path old = mTarget.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-old-" +
                                                      mTarget.filename().string());
        fs::remove_all(old);
        if (fs::exists(mTarget)) fs::rename(mTarget, old);
        fs::rename(mTmp, mTarget);
        fs::remove_all(old);
        mCommitted = true;
    }

private:
    fs::path mTarget, mTmp;
    bool mCommitted = false;
};

/// The full path of an executable on PATH, or "" when there is none.
inline std::string findOnPath(const std::string& program)
{
    const char* path = std::getenv("PATH");
    std::string dirs = path ? path : "/usr/local/bin:/usr/bin:/bin";
    std::size_t start = 0;
    while (start <= dirs.size()) {
        const std::size_t end = std::min(dirs.find(':', start), dirs.size());
        const std::string dir = dirs.substr(start, end - start);
        const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + program;
        if (::access(candidate.c_str(), X_OK) == 0 && fs::is_regular_file(candidate)) return candidate;
        start = end + 1;
    }
    return "";
}

/// Feeds raw RGB frames to an ffmpeg process that encodes them to H.264 in an MP4 (no shell:
/// the output path needs no quoting). ffmpeg's messages go to a log file next to the video and
/// the last line is quoted if it fails.
class FfmpegVideo {
public:
    FfmpegVideo(const std::string& ffmpeg, const std::string& outPath, const std::string& logPath, int width,
                int height, int fps)
        : mOut(outPath), mLog(logPath)
    {
        int fds[2];
        if (::pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("render.video: pipe failed: " + std::string(std::strerror(errno)));
        const std::string size = std::to_string(width) + "x" + std::to_string(height);
        const std::string rate = std::to_string(fps);
        std::vector<std::string> args = {ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
                                         "-s", size, "-framerate", rate, "-i", "-",
                                         // yuv420p needs even sizes.
                                         "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264",
                                         // ultrafast: a third of veryfast's CPU time at the
                                         // same PSNR (crf 20; the file about twice as large).
                                         "-preset", "ultrafast", "-crf", "20", "-pix_fmt", "yuv420p", "-movflags", "+faststart",
                                         outPath};
        std::vector<char*> argv;
        for (auto& a : args) argv.push_back(a.data());
        argv.push_back(nullptr);
        posix_spawn_file_actions_t actions;
        posix_spawn_file_actions_init(&actions);
        posix_spawn_file_actions_adddup2(&actions, fds[0], 0);
        posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
        posix_spawn_file_actions_addopen(&actions, 2, logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        const int rc = posix_spawn(&mPid, ffmpeg.c_str(), &actions, nullptr, argv.data(), environ);
        posix_spawn_file_actions_destroy(&actions);
        ::close(fds[0]);
        if (rc != 0) {
            ::close(fds[1]);
            throw std::runtime_error("render.video: could not start " + ffmpeg + ": " + std::strerror(rc));
        }
        mFd = fds[1];
        // A dying ffmpeg must surface as an error here, not kill the process with SIGPIPE.
        sigset_t pipeSet;
        sigemptyset(&pipeSet);
        sigaddset(&pipeSet, SIGPIPE);
        pthread_sigmask(SIG_BLOCK, &pipeSet, &mSavedMask);
    }

    ~FfmpegVideo()
    {
        if (mFd >= 0) {
            ::close(mFd);
            int status = 0;
            ::waitpid(mPid, &status, 0);
        }
        restoreSignals();
    }
    FfmpegVideo(const FfmpegVideo&) = delete;
    FfmpegVideo& operator=(const FfmpegVideo&) = delete;

    void write(const RgbImage& frame)
    {
        const uint8_t* p = frame.rgb.data();
        std::size_t left = frame.rgb.size();
        while (left > 0 && !mBroken) {
            const ssize_t n = ::write(mFd, p, left);
            if (n < 0) {
                if (errno == EINTR) continue;
                mBroken = true;  // ffmpeg exited: finish() reports why
                break;
            }
            p += n;
            left -= std::size_t(n);
        }
    }

    /// Closes the stream, waits for ffmpeg. @throw std::runtime_error when it failed.
    void finish()
    {
        ::close(mFd);
        mFd = -1;
        int status = 0;
        while (::waitpid(mPid, &status, 0) < 0 && errno == EINTR) {
        }
        restoreSignals();
        if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || mBroken) {
            std::string last;
            std::ifstream log(mLog);
            for (std::string line; std::getline(log, line);)
                if (!line.empty()) last = line;
            throw std::runtime_error("render.video: ffmpeg failed writing " + mOut +
                                     (last.empty() ? std::string() : ": " + last));
        }
    }

private:
    void restoreSignals()
    {
        if (!mSignalsRestored) {
            // Discard a SIGPIPE raised while blocked, then restore the caller's mask.
            sigset_t pipeSet;
            sigemptyset(&pipeSet);
            sigaddset(&pipeSet, SIGPIPE);
            const timespec zero{0, 0};
            while (sigtimedwait(&pipeSet, nullptr, &zero) > 0) {
            }
            pthread_sigmask(SIG_SETMASK, &mSavedMask, nullptr);
            mSignalsRestored = true;
        }
    }

    std::string mOut, mLog;
    pid_t mPid = -1;
    int mFd = -1;
    bool mBroken = false;
    bool mSignalsRestored = false;
    sigset_t mSavedMask;
};

} // namespace flyover
