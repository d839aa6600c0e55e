/// @file ffmpeg_video.h
/// @brief An ffmpeg process fed raw frames through a pipe, encoding an MP4.
#pragma once

#include "pipeline/yuv420.h"
#include "render/render_view.h"
#include "volume/fd_write.h"

#include <cerrno>
#include <csignal>
#include <cstring>
#include <fcntl.h>
#include <fstream>
#include <spawn.h>
#include <stdexcept>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

extern char** environ;

namespace flyover {

/// Feeds RGB frames to an ffmpeg process that encodes them to H.264 in an MP4 (no shell: the
/// output path needs no quoting). Frames of even width and height are converted to YUV 4:2:0
/// here (rgbToYuv420; ffmpeg's own RGB conversion cost it half of its CPU time); others go as
/// RGB with a pad to even sizes. ffmpeg's messages go to a log file next to the video and the
/// last line is quoted if it fails.
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
        mYuv = width % 2 == 0 && height % 2 == 0;
        std::vector<std::string> args = {ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt",
                                         mYuv ? "yuv420p" : "rgb24", "-s", size, "-framerate", rate, "-i", "-"};
        // yuv420p needs even sizes.
        if (!mYuv) args.insert(args.end(), {"-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"});
        // ultrafast: a third of veryfast's CPU time at the same PSNR (crf 20; the file about
        // twice as large).
        args.insert(args.end(), {"-c:v", "libx264", "-preset", "ultrafast", "-crf", "20", "-pix_fmt", "yuv420p",
                                 "-movflags", "+faststart", outPath});
        mWidth = width;
        mHeight = height;
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

    /// @throw std::invalid_argument when the frame's size is not the video's
    void write(const RgbImage& frame)
    {
        if (frame.width != mWidth || frame.height != mHeight ||
            frame.rgb.size() != std::size_t(mWidth) * std::size_t(mHeight) * 3)
            throw std::invalid_argument("render.video: a frame of " + std::to_string(frame.width) + " x " +
                                        std::to_string(frame.height) + " px for a video of " +
                                        std::to_string(mWidth) + " x " + std::to_string(mHeight));
        if (mYuv) rgbToYuv420(frame.rgb.data(), frame.width, frame.height, mPlanes);
        const uint8_t* p = mYuv ? mPlanes.data() : frame.rgb.data();
        const std::size_t size = mYuv ? mPlanes.size() : frame.rgb.size();
        if (!mBroken && writeFully(mFd, p, size) != 0) mBroken = true;  // ffmpeg exited: finish() reports why
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
    int mWidth = 0, mHeight = 0;
    bool mYuv = false;             ///< frames go to ffmpeg as YUV 4:2:0 (even sizes)
    std::vector<uint8_t> mPlanes;  ///< one frame's YUV planes, kept from frame to frame
    pid_t mPid = -1;
    int mFd = -1;
    bool mBroken = false;
    bool mSignalsRestored = false;
    sigset_t mSavedMask;
};

} // namespace flyover
