// The render stage as cached steps: each step keyed by its own parameters, the first
// fly-over pair written and announced first, and `flyover status` comparing the study's files
// with the record (a study whose frames/ holds another parameter set's output is not fresh).

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/render_output.h"
#include "pipeline/run_log.h"
#include "tests/pipeline/study_fixture.h"
#include "volume/error.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <set>
#include <sstream>

namespace fs = std::filesystem;
using namespace flyover;
using namespace flyover::test;

namespace {

std::string statusOf(const std::vector<StageStatus>& st, const std::string& stage)
{
    for (const auto& s : st)
        if (s.stage == stage) return s.state + (s.reason.empty() ? "" : ": " + s.reason);
    return "?";
}

bool haveFfmpeg() { return std::system("command -v ffmpeg >/dev/null 2>&1") == 0; }

/// PSNR (dB) of `b` against `a`, over every byte.
double psnr(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b)
{
    double se = 0;
    for (std::size_t i = 0; i < a.size(); ++i) se += (double(a[i]) - double(b[i])) * (double(a[i]) - double(b[i]));
    const double mse = se / double(a.size());
    return mse > 0 ? 10.0 * std::log10(255.0 * 255.0 / mse) : 99.0;
}

} // namespace

// The video's frames go to ffmpeg as YUV 4:2:0 made here (ffmpeg's own RGB conversion
// was half of its CPU time): Rec. 601 limited range, chroma from the mean of each 2 x 2 block.
TEST(RgbToYuv420, Rec601LimitedRangeWithBlockMeanChroma)
{
    // 4 x 2 pixels: a white/black block on the left, a reddish block on the right.
    const std::vector<uint8_t> rgb = {255, 255, 255, 0, 0, 0, 255, 0,   0,   255, 128, 0,    // row 0
                                      0,   0,   0,   255, 255, 255, 0, 0, 255, 200, 100, 50};  // row 1
    std::vector<uint8_t> yuv;
    rgbToYuv420(rgb.data(), 4, 2, yuv);
    ASSERT_EQ(yuv.size(), 8u + 2u + 2u) << "4 x 2 luma bytes, then 2 x 1 Cb and 2 x 1 Cr";
    EXPECT_EQ(int(yuv[0]), 235) << "white";
    EXPECT_EQ(int(yuv[1]), 16) << "black";
    // Every value against the Rec. 601 formula in double, rounded to nearest (the fixed point
    // may round the other way only within 0.01 of a half).
    auto expectRounded = [](int got, double exact, const std::string& what) {
        EXPECT_LE(std::fabs(got - exact), 0.51) << what << ": got " << got << ", exact " << exact;
    };
    for (int i = 0; i < 8; ++i) {
        const double r = rgb[std::size_t(3 * i)], g = rgb[std::size_t(3 * i + 1)], b = rgb[std::size_t(3 * i + 2)];
        expectRounded(yuv[std::size_t(i)], 16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0,
                      "luma of pixel " + std::to_string(i));
    }
    for (int block = 0; block < 2; ++block) {
        double r = 0, g = 0, b = 0;  // the block's mean
        for (const int row : {0, 1})
            for (const int col : {0, 1}) {
                const std::size_t p = std::size_t(3 * (row * 4 + 2 * block + col));
                r += rgb[p] / 4.0, g += rgb[p + 1] / 4.0, b += rgb[p + 2] / 4.0;
            }
        expectRounded(yuv[std::size_t(8 + block)], 128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0,
                      "Cb of block " + std::to_string(block));
        expectRounded(yuv[std::size_t(10 + block)], 128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0,
                      "Cr of block " + std::to_string(block));
    }
    EXPECT_THROW(rgbToYuv420(rgb.data(), 3, 2, yuv), std::invalid_argument) << "odd width";
}

// The plain rule of rgbToYuv420, one pixel and one block at a time, as it was before the SSE2
// version: the reference that every byte of the fast one must equal.
namespace {
std::vector<uint8_t> plainRgbToYuv420(const std::vector<uint8_t>& rgb, std::size_t w, std::size_t h)
{
    auto fix = [](double c) { return int32_t(c / 255.0 * 65536.0 + (c < 0 ? -0.5 : 0.5)); };
    const int32_t YR = fix(65.481), YG = fix(128.553), YB = fix(24.966);
    const int32_t UR = fix(-37.797), UG = fix(-74.203), UB = fix(112.0);
    const int32_t VR = fix(112.0), VG = fix(-93.786), VB = fix(-18.214);
    std::vector<uint8_t> yuv(w * h + 2 * (w / 2) * (h / 2));
    for (std::size_t p = 0; p < w * h; ++p)
        yuv[p] = uint8_t((YR * rgb[3 * p] + YG * rgb[3 * p + 1] + YB * rgb[3 * p + 2] + (16 << 16) + (1 << 15)) >> 16);
    for (std::size_t cy = 0; cy < h / 2; ++cy)
        for (std::size_t cx = 0; cx < w / 2; ++cx) {
            int32_t r = 0, g = 0, b = 0;
            for (const std::size_t row : {2 * cy, 2 * cy + 1})
                for (const std::size_t col : {2 * cx, 2 * cx + 1}) {
                    const std::size_t i = 3 * (row * w + col);
                    r += rgb[i], g += rgb[i + 1], b += rgb[i + 2];
                }
            const std::size_t c = cy * (w / 2) + cx;
            yuv[w * h + c] = uint8_t((UR * r + UG * g + UB * b + (128 << 18) + (1 << 17)) >> 18);
            yuv[w * h + (w / 2) * (h / 2) + c] = uint8_t((VR * r + VG * g + VB * b + (128 << 18) + (1 << 17)) >> 18);
        }
    return yuv;
}
} // namespace

// The SSE2 conversion (eight pixels at a time, a scalar tail) gives the plain rule's bytes for
// random images of every even width from 2 to 64 (tails of every length, too narrow for a vector
// step), the video's 1028 x 512, and images of only extreme values.
TEST(RgbToYuv420, SameBytesAsThePlainRuleForRandomImagesOfManySizes)
{
    std::mt19937 rng(15);
    std::vector<std::pair<std::size_t, std::size_t>> sizes;
    for (std::size_t w = 2; w <= 64; w += 2) sizes.emplace_back(w, 2 + 2 * (w % 3));
    sizes.emplace_back(1028, 512);
    sizes.emplace_back(1030, 6);
    for (const auto& [w, h] : sizes)
        for (const int kind : {0, 1, 2}) {  // uniform random, only 0 and 255, near 255
            std::vector<uint8_t> rgb(w * h * 3);
            for (auto& c : rgb)
                c = kind == 0 ? uint8_t(rng()) : kind == 1 ? uint8_t(rng() % 2 ? 255 : 0) : uint8_t(250 + rng() % 6);
            std::vector<uint8_t> yuv;
            rgbToYuv420(rgb.data(), int(w), int(h), yuv);
            const std::vector<uint8_t> expected = plainRgbToYuv420(rgb, w, h);
            ASSERT_EQ(yuv.size(), expected.size()) << w << " x " << h;
            const auto diff = std::mismatch(yuv.begin(), yuv.end(), expected.begin());
            ASSERT_TRUE(diff.first == yuv.end())
                << w << " x " << h << " (kind " << kind << "): byte " << (diff.first - yuv.begin()) << " of "
                << yuv.size() << " (luma plane: " << w * h << " bytes) is " << int(*diff.first) << ", the plain rule gives "
                << int(*diff.second);
        }
}

// A rendered-like image through FfmpegVideo and back through ffmpeg's decoder keeps its pixels
// within the encoder's loss (crf 20), for the YUV path (even sizes) and the RGB + pad path.
TEST(FfmpegVideo, EncodedFramesDecodeCloseToTheInput)
{
    if (!haveFfmpeg()) GTEST_SKIP() << "no ffmpeg on PATH";
    const std::string ffmpeg = findOnPath("ffmpeg");
    const fs::path dir = fs::temp_directory_path() / ("flyover-video-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    for (const auto& [w, h] : std::vector<std::pair<int, int>>{{64, 48}, {63, 47}}) {
        RgbImage frame;
        frame.width = w;
        frame.height = h;
        frame.rgb.resize(std::size_t(w) * std::size_t(h) * 3);
        for (int y = 0; y < h; ++y)  // smooth tissue-like shading with a dark background corner
            for (int x = 0; x < w; ++x) {
                const double s = (x + y < 12) ? 0.08 : 0.4 + 0.6 * std::sin(0.05 * x + 0.07 * y) * std::sin(0.05 * x + 0.07 * y);
                uint8_t* p = &frame.rgb[(std::size_t(y) * std::size_t(w) + std::size_t(x)) * 3];
                p[0] = uint8_t(std::lround(237 * s)), p[1] = uint8_t(std::lround(158 * s)), p[2] = uint8_t(std::lround(140 * s));
            }
        const std::string mp4 = (dir / ("v" + std::to_string(w) + ".mp4")).string();
        {
            FfmpegVideo video(ffmpeg, mp4, (dir / "log.txt").string(), w, h, 25);
            for (int k = 0; k < 5; ++k) video.write(frame);
            RgbImage wrong = frame;
            wrong.width -= 2;
            EXPECT_THROW(video.write(wrong), std::invalid_argument) << "a frame of another size";
            video.finish();
        }
        const std::string raw = (dir / "out.rgb").string();
        const std::string cmd = "ffmpeg -loglevel error -y -i '" + mp4 + "' -vf format=rgb24,crop=" + std::to_string(w) + ":" +
                                std::to_string(h) + ":0:0 -frames:v 1 -f rawvideo -pix_fmt rgb24 '" + raw + "'";
        ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
        std::ifstream in(raw, std::ios::binary);
        std::vector<uint8_t> decoded((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        ASSERT_EQ(decoded.size(), frame.rgb.size()) << w << " x " << h << ": decoded frame size";
        // Measured: 39.4 dB through the YUV path, 36.2 dB through ffmpeg's RGB conversion (the
        // odd size, padded); the margins catch a wrong matrix, range or plane order (< 20 dB).
        const double minDb = (w % 2 == 0 && h % 2 == 0) ? 38.0 : 34.0;
        EXPECT_GE(psnr(frame.rgb, decoded), minDb) << w << " x " << h << ": decoded frame PSNR";
    }
    fs::remove_all(dir);
}

TEST_F(StudyTest, VideoFpsRecomputesTheVideoOnly)
{
    if (!haveFfmpeg()) GTEST_SKIP() << "no ffmpeg on PATH";
    RunOptions o = options("fps");
    o.params.render.video = true;
    const auto first = runPipeline(o);
    ASSERT_TRUE(fs::exists(o.studyDir + "/video/flyover.mp4"));
    EXPECT_EQ(readJson(o.studyDir + "/video/poses.json").at("fps"), 25);
    // The video takes the pairs the frames step rendered in the same run (the same cameras)
    // from frames/: as many as the two steps' centerline indices have in common.
    auto videoReport = [&] {
        const nlohmann::json manifest = readJson(o.studyDir + "/manifest.json");
        for (const auto& st : manifest.at("stages"))
            if (st.at("stage") == "video") return st.at("report");
        return nlohmann::json();
    };
    {
        std::set<std::size_t> frameIndices;
        const nlohmann::json framePoses = readJson(o.studyDir + "/frames/poses.json");
        const nlohmann::json videoPoses = readJson(o.studyDir + "/video/poses.json");
        for (const auto& f : framePoses.at("frames")) frameIndices.insert(f.at("centerline_index").get<std::size_t>());
        std::size_t common = 0;
        for (const auto& f : videoPoses.at("frames"))
            common += frameIndices.count(f.at("centerline_index").get<std::size_t>());
        EXPECT_GT(common, 0u);
        EXPECT_EQ(videoReport().value("frames_from_frame_pairs", std::size_t(0)), common);
    }

    o.params.render.videoFps = 12;
    const auto second = runPipeline(o);
    const auto m = computedStages(second);
    EXPECT_EQ(m, (std::map<std::string, bool>{{"ingest", false}, {"segment", false}, {"centerline", false},
                                              {"mesh", false}, {"frames", false}, {"flythrough", false},
                                              {"overviews", false}, {"video", true}, {"coverage", false},
                                              {"polyps", false}}))
        << "render.video_fps changed: only the video may be recomputed";
    EXPECT_EQ(readJson(o.studyDir + "/video/poses.json").at("fps"), 12);
    EXPECT_EQ(videoReport().value("frames_from_frame_pairs", std::size_t(1)), 0u)
        << "the frames step did not run: every video frame is rendered";
    EXPECT_NE(outputDigests(first)["video"], outputDigests(second)["video"]);
    for (const char* step : {"frames", "flythrough", "overviews", "coverage"})
        EXPECT_EQ(outputDigests(first)[step], outputDigests(second)[step]) << step;

    StatusOptions so;
    so.studyDir = o.studyDir;
    for (const auto& st : studyStatus(so)) EXPECT_EQ(st.state, "fresh") << st.stage << ": " << st.reason;
    so.params = o.params;
    so.paramsGiven = true;
    so.params.render.videoFps = 30;
    const auto st = studyStatus(so);
    EXPECT_EQ(statusOf(st, "frames"), "fresh");
    EXPECT_EQ(statusOf(st, "coverage"), "fresh");
    EXPECT_NE(statusOf(st, "video").find("render.video_fps"), std::string::npos) << statusOf(st, "video");
}

TEST_F(StudyTest, FirstPairIsWrittenAndAnnouncedBeforeTheOtherRenderSteps)
{
    RunOptions o = options("firstpair");
    std::ostringstream out;
    RunLog log(RunLog::Mode::Json, out);
    o.log = &log;
    runPipeline(o);

    std::vector<nlohmann::json> events;
    std::istringstream lines(out.str());
    for (std::string line; std::getline(lines, line);) events.push_back(nlohmann::json::parse(line));
    std::size_t firstPair = events.size();
    for (std::size_t i = 0; i < events.size(); ++i)
        if (events[i].at("event") == "first_pair") {
            EXPECT_EQ(firstPair, events.size()) << "announced twice";
            firstPair = i;
        }
    ASSERT_LT(firstPair, events.size()) << "no first_pair event in:\n" << out.str();
    const auto& e = events[firstPair];
    EXPECT_EQ(e.at("path"), o.studyDir + "/frames/pair_0000.png");
    EXPECT_GT(e.at("seconds_since_start").get<double>(), 0.0);
    EXPECT_TRUE(fs::exists(e.at("path").get<std::string>()));
    for (std::size_t i = 0; i < firstPair; ++i) {
        const std::string stage = events[i].value("stage", "");
        EXPECT_FALSE(stage != "frames" && std::find(RENDER_STEPS.begin(), RENDER_STEPS.end(), stage) != RENDER_STEPS.end())
            << "render step " << stage << " ran before the first pair was announced: " << events[i].dump();
        EXPECT_FALSE(events[i].at("event") == "stage_finished" && stage == "frames") << "frames finished first";
    }
    // An unchanged re-run renders nothing and announces nothing.
    std::ostringstream out2;
    RunLog log2(RunLog::Mode::Json, out2);
    o.log = &log2;
    runPipeline(o);
    EXPECT_EQ(out2.str().find("first_pair"), std::string::npos) << out2.str();
}

// The early node "render arrays of the surface" prepares the render scene's arrays and normals
// from the mesh in memory as soon as the mesh stage hands it on, beside its writing and hashing
// of surface.ply; the frames step renders the first pair from a scene of only the triangles its
// rays can meet, then builds the whole scene. The frames (pair_0000.png first) are those of the
// frames step run from surface.ply (the mesh stage reused) and with one thread.
TEST_F(StudyTest, SurfaceArraysPreparedEarlyRenderTheSameFrames)
{
    auto framesReport = [](const nlohmann::json& manifest) {
        for (const auto& s : manifest.at("stages"))
            if (s.at("stage") == "frames") return s.at("report");
        ADD_FAILURE() << "no frames stage in the manifest";
        return nlohmann::json();
    };
    auto begun = [&](const nlohmann::json& manifest) {
        return framesReport(manifest).at("surface_prepared_early").get<bool>();
    };
    // The first pair came from a frustum cull that dropped triangles.
    auto expectCulled = [&](const nlohmann::json& manifest, const std::string& what) {
        const nlohmann::json scene = framesReport(manifest).at("first_pair_scene");
        EXPECT_EQ(scene.at("scene"), "frustum cull of the whole surface") << what;
        EXPECT_LT(scene.value("pair_triangles", 0u), scene.value("surface_triangles", 0u)) << what;
        EXPECT_LT(scene.value("frame_radius_triangles", 0u), scene.value("surface_triangles", 0u)) << what;
    };
    auto readBytes = [](const std::string& path) {
        std::ifstream in(path, std::ios::binary);
        return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    };
    RunOptions o = options("scenebegun");
    o.untilStage = "frames";
    const nlohmann::json early = runPipeline(o);
    EXPECT_TRUE(begun(early)) << "the frames step did not take the arrays prepared beside the mesh stage";
    expectCulled(early, "mesh in memory");
    const std::string firstPair = readBytes(o.studyDir + "/frames/pair_0000.png");
    ASSERT_FALSE(firstPair.empty());

    // Reused mesh: the arrays from surface.ply.
    fs::remove_all(o.studyDir + "/frames");
    o.forceStage = "frames";
    const nlohmann::json fromFile = runPipeline(o);
    EXPECT_FALSE(computedStages(fromFile).at("mesh"));
    EXPECT_TRUE(computedStages(fromFile).at("frames"));
    EXPECT_FALSE(begun(fromFile)) << "arrays prepared early although the mesh stage was reused";
    expectCulled(fromFile, "surface.ply");
    EXPECT_EQ(readBytes(o.studyDir + "/frames/pair_0000.png"), firstPair)
        << "pair_0000.png from surface.ply differs from the one from the mesh in memory";
    EXPECT_EQ(outputDigests(fromFile).at("frames"), outputDigests(early).at("frames"));

    // One thread: the early node runs between the mesh stage and the frames step (its edges
    // order it), the same frames.
    RunOptions one = options("scenebegun-onethread");
    one.untilStage = "frames";
    nlohmann::json oneThread;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        oneThread = runPipeline(one);
    }
    EXPECT_TRUE(begun(oneThread)) << "the early node did not run before the frames step with one thread";
    EXPECT_EQ(outputDigests(oneThread).at("mesh"), outputDigests(early).at("mesh"));
    EXPECT_EQ(outputDigests(oneThread).at("frames"), outputDigests(early).at("frames"));

    // The first pair is confirmed on the whole scene: the same pixels here ...
    const nlohmann::json check = framesReport(early).at("first_pair_check");
    EXPECT_TRUE(check.at("confirmed_on_whole_scene").get<bool>());
    EXPECT_EQ(check.at("differing_pixels").get<std::size_t>(), 0u);
    EXPECT_FALSE(check.at("replaced").get<bool>());
    // ... and a cull that drops what the cameras see (its planes 3 mm inwards, through the test
    // hook) shows a different first pair, which the frames step then replaces by the whole
    // scene's: frames/ ends the same as without the hook.
    RunOptions bad = options("scenebegun-badcull");
    bad.untilStage = "frames";
    ::setenv("FLYOVER_TEST_FIRST_PAIR_CULL_MM", "-3", 1);
    nlohmann::json badCull;
    try {
        badCull = runPipeline(bad);
    } catch (...) {
        ::unsetenv("FLYOVER_TEST_FIRST_PAIR_CULL_MM");
        throw;
    }
    ::unsetenv("FLYOVER_TEST_FIRST_PAIR_CULL_MM");
    const nlohmann::json badCheck = framesReport(badCull).at("first_pair_check");
    EXPECT_GT(badCheck.at("differing_pixels").get<std::size_t>(), 0u)
        << "a cull 3 mm inside the frustum left the first pair unchanged: the confirmation saw nothing";
    EXPECT_TRUE(badCheck.at("replaced").get<bool>());
    EXPECT_EQ(readBytes(bad.studyDir + "/frames/pair_0000.png"), firstPair)
        << "the replaced pair_0000.png is not the whole scene's";
    EXPECT_EQ(outputDigests(badCull).at("frames"), outputDigests(early).at("frames"));
}

// The video, the longest render step, starts first of the steps after the frames (then
// coverage), so that it does not run alone at the end of the run. With one thread
// the order is the whole story; the MP4 must be the same, byte for byte, whether its frames are
// rendered one at a time or several at once.
TEST_F(StudyTest, VideoStartsFirstAfterTheFramesAndIsTheSameOnAnyNumberOfThreads)
{
    if (!haveFfmpeg()) GTEST_SKIP() << "no ffmpeg on PATH";
    RunOptions o = options("videofirst");
    o.params.render.video = true;
    o.params.render.videoStepMm = 4;  // many frames in flight at once
    std::ostringstream out;
    RunLog log(RunLog::Mode::Json, out);
    o.log = &log;
    std::map<std::string, nlohmann::json> oneThread;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        oneThread = outputDigests(runPipeline(o));
    }
    std::vector<std::string> started;
    bool framesDone = false;
    std::istringstream lines(out.str());
    for (std::string line; std::getline(lines, line);) {
        const auto e = nlohmann::json::parse(line);
        if (e.at("event") == "stage_finished" && e.value("stage", "") == "frames") framesDone = true;
        if (framesDone && e.at("event") == "stage_started") started.push_back(e.at("stage"));
    }
    ASSERT_EQ(started.size(), 5u) << "flythrough, overviews, video, coverage and polyps: " << out.str();
    EXPECT_EQ(started[0], "video") << "the render steps after the frames started in this order: " << started[0]
                                   << ", " << started[1] << ", " << started[2] << ", " << started[3];
    EXPECT_EQ(started[1], "coverage");

    o.log = nullptr;
    o.studyDir += "-threads";
    const auto manyThreads = outputDigests(runPipeline(o));
    EXPECT_EQ(oneThread.at("video"), manyThreads.at("video"))
        << "video/ (flyover.mp4, poses.json) differs between one thread and the default number";
    EXPECT_EQ(oneThread.at("frames"), manyThreads.at("frames"));
}

// A thread's pair image is its own while the pair is rendered and written: waiting for the
// pair's tiles (a nested parallel loop), the thread must not take up another pair that renders
// into the same image (frames differed between runs under load). Many threads on few cores
// make such steals frequent; the frames, fly-through and coverage must be one thread's.
TEST_F(StudyTest, RenderStepsAreOneThreadsUnderNestedStealing)
{
    RunOptions o = options("stealing-one");
    o.params.render.video = false;
    std::map<std::string, nlohmann::json> oneThread;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        oneThread = outputDigests(runPipeline(o));
    }
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 16);
    tbb::task_arena arena(16);
    for (int run = 0; run < 3; ++run) {
        RunOptions m = options("stealing-many-" + std::to_string(run));
        m.params.render.video = false;
        std::map<std::string, nlohmann::json> many;
        arena.execute([&] { many = outputDigests(runPipeline(m)); });
        for (const char* step : {"frames", "flythrough", "coverage"})
            EXPECT_EQ(oneThread.at(step), many.at(step)) << "run " << run << ": " << step
                                                         << "/ differs from one thread's";
    }
}

TEST_F(StudyTest, StatusComparesTheStudysFilesWithTheRecord)
{
    RunOptions o = options("otherparams");
    runPipeline(o);
    const std::string framesA = artifactDigest(o.studyDir + "/frames");

    // Other frame parameters on a copy of the study (as render_bench works): the study itself
    // is untouched and stays fresh.
    const std::string copy = studyDir("otherparams-copy");
    copyStudy(o.studyDir, copy);
    RunOptions b = o;
    b.studyDir = copy;
    b.params.render.frameStepMm = 60;
    runPipeline(b);
    EXPECT_NE(artifactDigest(copy + "/frames"), framesA) << "the copy's frames must be other frames";
    EXPECT_EQ(artifactDigest(o.studyDir + "/frames"), framesA) << "working on the copy changed the study";
    StatusOptions so;
    so.studyDir = o.studyDir;
    so.params = o.params;
    so.paramsGiven = true;
    for (const auto& st : studyStatus(so)) EXPECT_EQ(st.state, "fresh") << st.stage << ": " << st.reason;
    EXPECT_THROW(copyStudy(o.studyDir, copy), InputError) << "copying onto an existing folder";

    // The same run in the study itself leaves frames/ holding the other parameters' output:
    // status against the first parameters must say so, not "fresh".
    b.studyDir = o.studyDir;
    runPipeline(b);
    const std::string frames = statusOf(studyStatus(so), "frames");
    EXPECT_EQ(frames.rfind("stale", 0), 0u) << frames;
    EXPECT_NE(frames.find("other frames parameters"), std::string::npos) << frames;
    // A run with the first parameters restores them from the cache.
    const auto m = computedStages(runPipeline(o));
    EXPECT_FALSE(m.at("frames"));
    EXPECT_EQ(artifactDigest(o.studyDir + "/frames"), framesA);
    EXPECT_EQ(statusOf(studyStatus(so), "frames"), "fresh");

    // A frames/ changed by hand (one pair more) is not fresh either.
    fs::copy_file(o.studyDir + "/frames/pair_0000.png", o.studyDir + "/frames/pair_9999.png");
    const std::string edited = statusOf(studyStatus(so), "frames");
    EXPECT_NE(edited.find("modified"), std::string::npos) << edited;
}
