// A small-phantom study shared by the pipeline tests: the phantom is generated once per test
// process into a temporary folder, and each test gets its own study folder.
#pragma once

#include "colon/phantom.h"
#include "colon/phantom_io.h"
#include "colon/colon_study.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <filesystem>
#include <string>

namespace flyover::test {

inline constexpr uint64_t STUDY_SEED = 3;

class StudyTest : public ::testing::Test {
protected:
    static void SetUpTestSuite()
    {
        openvdb::initialize();
        sRoot = std::filesystem::temp_directory_path() / ("flyover-study-" + std::to_string(::getpid()));
        std::filesystem::remove_all(sRoot);
        std::filesystem::create_directories(sRoot);
        PhantomParams pp;
        pp.size = PhantomSize::Small;
        pp.seed = STUDY_SEED;
        sPhantom = new Phantom(makePhantom(pp));
        writePhantom(*sPhantom, pp, ctPath(), (sRoot / "truth.json").string(), "");
    }
    static void TearDownTestSuite()
    {
        delete sPhantom;
        sPhantom = nullptr;
        std::filesystem::remove_all(sRoot);
    }

    static std::string ctPath() { return (sRoot / "ct.nii.gz").string(); }
    std::string studyDir(const std::string& name) const { return (sRoot / name).string(); }

    /// Options for a quick run: small frames, few of them.
    RunOptions options(const std::string& study) const
    {
        RunOptions o;
        o.ctPath = ctPath();
        o.studyDir = studyDir(study);
        o.params.render.widthPx = o.params.render.heightPx = 96;
        o.params.render.frameStepMm = 150;
        o.params.render.overviewPx = 128;
        // The costly extras of the render stage, cut down: their own tests cover them.
        o.params.render.coveragePx = 32;
        o.params.render.coverageStepMm = 20;
        o.params.render.video = false;
        o.params.render.videoStepMm = 50;
        return o;
    }

    static inline std::filesystem::path sRoot;
    static inline Phantom* sPhantom = nullptr;
};

/// The render steps, each its own stage of the graph, in pipeline order.
inline const std::vector<std::string> RENDER_STEPS{"frames", "flythrough", "overviews", "video", "coverage"};

/// `stages` plus every render step, each computed (true) or reused (false) as `render`, and
/// the polyps stage (beside the render steps, on the same inputs and more) as `render` unless
/// `stages` names it.
inline std::map<std::string, bool> withRenderSteps(std::map<std::string, bool> stages, bool render)
{
    for (const auto& s : RENDER_STEPS) stages[s] = render;
    stages.emplace("polyps", render);
    return stages;
}

/// Stage name -> computed (true) or reused (false), from a manifest.
inline std::map<std::string, bool> computedStages(const nlohmann::json& manifest)
{
    std::map<std::string, bool> m;
    for (const auto& s : manifest["stages"]) m[s["stage"].get<std::string>()] = s["computed"].get<bool>();
    return m;
}

/// Stage name -> output digests, from a manifest.
inline std::map<std::string, nlohmann::json> outputDigests(const nlohmann::json& manifest)
{
    std::map<std::string, nlohmann::json> m;
    for (const auto& s : manifest["stages"]) m[s["stage"].get<std::string>()] = s["outputs"];
    return m;
}

} // namespace flyover::test
