/// @file render_output.h
/// @brief What the render steps of `flyover run` and `flyover inspect` share to write their
///        outputs (internal to pipeline/): folders written under a temporary name and renamed
///        into place, the ffmpeg encoder fed raw frames, the cameras' JSON.
#pragma once

#include "render/camera.h"
#include "render/render_view.h"
#include "volume/fd_write.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>

#include <cerrno>
#include <cstdint>
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

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

#if defined(__SSE2__)
namespace yuv_detail {
// Four RGB pixels from p (reads 16 bytes: 4 past the 4th pixel) as 16-bit lanes R G B G of
// pixels 0 and 1 (`lo`) and of pixels 2 and 3 (`hi`): G twice, so that a coefficient too large
// for 16 bits goes as two halves through _mm_madd_epi16.
inline void gatherRgbg(const uint8_t* p, __m128i& lo, __m128i& hi)
{
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p));
    const __m128i zero = _mm_setzero_si128();
    const __m128i p01 = _mm_unpacklo_epi32(v, _mm_srli_si128(v, 3));
    const __m128i p23 = _mm_unpacklo_epi32(_mm_srli_si128(v, 6), _mm_srli_si128(v, 9));
    lo = _mm_unpacklo_epi8(p01, zero);
    hi = _mm_unpacklo_epi8(p23, zero);
    lo = _mm_shufflehi_epi16(_mm_shufflelo_epi16(lo, _MM_SHUFFLE(1, 2, 1, 0)), _MM_SHUFFLE(1, 2, 1, 0));
    hi = _mm_shufflehi_epi16(_mm_shufflelo_epi16(hi, _MM_SHUFFLE(1, 2, 1, 0)), _MM_SHUFFLE(1, 2, 1, 0));
}

// Sums of adjacent 32-bit lanes: [a0 + a1, a2 + a3, b0 + b1, b2 + b3].
inline __m128i pairSums(__m128i a, __m128i b)
{
    const __m128 fa = _mm_castsi128_ps(a), fb = _mm_castsi128_ps(b);
    return _mm_add_epi32(_mm_castps_si128(_mm_shuffle_ps(fa, fb, _MM_SHUFFLE(2, 0, 2, 0))),
                         _mm_castps_si128(_mm_shuffle_ps(fa, fb, _MM_SHUFFLE(3, 1, 3, 1))));
}

// cR * R + cG * G + cB * B of the four gathered pixels, exact in 32 bits.
inline __m128i weigh(__m128i lo, __m128i hi, __m128i coeffs)
{
    return pairSums(_mm_madd_epi16(lo, coeffs), _mm_madd_epi16(hi, coeffs));
}
} // namespace yuv_detail
#endif

/// RGB (3 bytes per pixel, row-major) to planar YUV 4:2:0 as H.264 takes it: BT.601 limited
/// range (Y 16..235, Cb and Cr 16..240), each chroma sample from the mean of its 2 x 2 block of
/// pixels (centred siting, as ffmpeg's scaler takes it from RGB). Fixed point with 16-bit
/// coefficients, rounded to nearest. `yuv` gets width * height luma bytes, then the Cb and the
/// Cr plane of (width / 2) * (height / 2) bytes each. Width and height must be even. With SSE2,
/// eight pixels at a time, byte for byte the same as the scalar rule, in half the CPU time.
/// @throw std::invalid_argument for odd or non-positive sizes or a buffer of the wrong size
inline void rgbToYuv420(const uint8_t* rgb, int width, int height, std::vector<uint8_t>& yuv)
{
    if (width <= 0 || height <= 0 || width % 2 != 0 || height % 2 != 0)
        throw std::invalid_argument("rgbToYuv420: width and height must be even and positive, got " +
                                    std::to_string(width) + " x " + std::to_string(height));
    // Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255 and so on (Rec. 601), times 2^16.
    constexpr auto fix = [](double c) { return int32_t(c / 255.0 * 65536.0 + (c < 0 ? -0.5 : 0.5)); };
    constexpr int32_t YR = fix(65.481), YG = fix(128.553), YB = fix(24.966);
    constexpr int32_t UR = fix(-37.797), UG = fix(-74.203), UB = fix(112.0);
    constexpr int32_t VR = fix(112.0), VG = fix(-93.786), VB = fix(-18.214);
    constexpr int32_t YOffset = (16 << 16) + (1 << 15), UVOffset = (128 << 18) + (1 << 17);
    const std::size_t w = std::size_t(width), h = std::size_t(height), cw = w / 2;
    yuv.resize(w * h + 2 * cw * (h / 2));
    uint8_t* yPlane = yuv.data();
    uint8_t* uPlane = yPlane + w * h;
    uint8_t* vPlane = uPlane + cw * (h / 2);
#if defined(__SSE2__)
    // SSE2, eight pixels of two rows at a time; every value is the same integer expression as in
    // the scalar rule below (exact in 32 bits, so the order of the sums does not matter; a chroma
    // sum weighs each of the four pixels and adds them, which is the weighted sum of the block).
    static_assert(YG / 2 + 1 < 32768 && YR < 32768 && YB < 32768 && UB < 32768 && VR < 32768 &&
                      -UR < 32768 && -UG < 32768 && -VG < 32768 && -VB < 32768,
                  "16-bit coefficients for _mm_madd_epi16");
    const __m128i yCoeffs = _mm_setr_epi16(int16_t(YR), int16_t(YG - YG / 2), int16_t(YB), int16_t(YG / 2),
                                           int16_t(YR), int16_t(YG - YG / 2), int16_t(YB), int16_t(YG / 2));
    const __m128i uCoeffs = _mm_setr_epi16(int16_t(UR), int16_t(UG), int16_t(UB), 0, int16_t(UR), int16_t(UG), int16_t(UB), 0);
    const __m128i vCoeffs = _mm_setr_epi16(int16_t(VR), int16_t(VG), int16_t(VB), 0, int16_t(VR), int16_t(VG), int16_t(VB), 0);
    const __m128i yOffset = _mm_set1_epi32(YOffset), uvOffset = _mm_set1_epi32(UVOffset);
    // A group of eight pixels reads 4 bytes past its last one: stop 2 pixels (6 bytes) early.
    const std::size_t vectorEnd = w >= 10 ? (w - 2) / 8 * 8 : 0;
#endif
    for (std::size_t cy = 0; cy < h / 2; ++cy) {
        const uint8_t* a = rgb + 2 * cy * w * 3;
        const uint8_t* b = a + w * 3;
        uint8_t* ya = yPlane + 2 * cy * w;
        uint8_t* yb = ya + w;
        uint8_t* u = uPlane + cy * cw;
        uint8_t* v = vPlane + cy * cw;
        std::size_t x = 0;
#if defined(__SSE2__)
        for (; x < vectorEnd; x += 8) {
            __m128i a0, a1, a2, a3, b0, b1, b2, b3;  // pixels x..x+3 (0, 1) and x+4..x+7 (2, 3)
            yuv_detail::gatherRgbg(a + 3 * x, a0, a1);
            yuv_detail::gatherRgbg(a + 3 * x + 12, a2, a3);
            yuv_detail::gatherRgbg(b + 3 * x, b0, b1);
            yuv_detail::gatherRgbg(b + 3 * x + 12, b2, b3);
            auto luma = [&](__m128i lo0, __m128i hi0, __m128i lo1, __m128i hi1, uint8_t* out) {
                const __m128i l0 = _mm_srai_epi32(_mm_add_epi32(yuv_detail::weigh(lo0, hi0, yCoeffs), yOffset), 16);
                const __m128i l1 = _mm_srai_epi32(_mm_add_epi32(yuv_detail::weigh(lo1, hi1, yCoeffs), yOffset), 16);
                const __m128i w16 = _mm_packs_epi32(l0, l1);
                _mm_storel_epi64(reinterpret_cast<__m128i*>(out), _mm_packus_epi16(w16, w16));
            };
            luma(a0, a1, a2, a3, ya + x);
            luma(b0, b1, b2, b3, yb + x);
            auto chroma = [&](__m128i coeffs, uint8_t* out) {
                const __m128i s0 = _mm_add_epi32(yuv_detail::weigh(a0, a1, coeffs), yuv_detail::weigh(b0, b1, coeffs));
                const __m128i s1 = _mm_add_epi32(yuv_detail::weigh(a2, a3, coeffs), yuv_detail::weigh(b2, b3, coeffs));
                const __m128i c = _mm_srai_epi32(_mm_add_epi32(yuv_detail::pairSums(s0, s1), uvOffset), 18);
                const __m128i c16 = _mm_packs_epi32(c, c);
                const int32_t bytes = _mm_cvtsi128_si32(_mm_packus_epi16(c16, c16));
                std::memcpy(out, &bytes, 4);
            };
            chroma(uCoeffs, u + x / 2);
            chroma(vCoeffs, v + x / 2);
        }
#endif
        for (; x < w; x += 2) {
            for (const uint8_t* in : {a, b}) {
                uint8_t* out = in == a ? ya : yb;
                for (std::size_t k = x; k < x + 2; ++k)
                    out[k] = uint8_t((YR * in[3 * k] + YG * in[3 * k + 1] + YB * in[3 * k + 2] + YOffset) >> 16);
            }
            const std::size_t i = 3 * x;
            // Sums of the four pixels: the mean's coefficients are a quarter, hence >> 18.
            const int32_t r = a[i] + a[i + 3] + b[i] + b[i + 3];
            const int32_t g = a[i + 1] + a[i + 4] + b[i + 1] + b[i + 4];
            const int32_t bl = a[i + 2] + a[i + 5] + b[i + 2] + b[i + 5];
            u[x / 2] = uint8_t((UR * r + UG * g + UB * bl + UVOffset) >> 18);
            v[x / 2] = uint8_t((VR * r + VG * g + VB * bl + UVOffset) >> 18);
        }
    }
}

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
