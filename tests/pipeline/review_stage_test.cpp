// The render stage's review views (render.review): review/ frames and poses, and the fly-over
// with review in coverage/coverage.json, on the small phantom study of the pipeline tests.
#include "pipeline/artifact_io.h"
#include "colon/colon_study.h"
#include "tests/pipeline/study_fixture.h"

#include <gtest/gtest.h>

#include <filesystem>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover::test {
namespace {

class ReviewStage : public StudyTest {};

TEST_F(ReviewStage, WritesReviewFramesPosesAndCoverageWithReview)
{
    RunOptions o = options("review-on");
    o.params.render.flythroughFrames = false;
    // Fly-over views 60 mm apart leave gaps between them for the review to fill.
    o.params.render.coverageStepMm = 60;
    runPipeline(o);
    const fs::path study = o.studyDir;
    const json cov = readJson((study / "coverage/coverage.json").string());
    SCOPED_TRACE("small phantom seed " + std::to_string(STUDY_SEED) + ", study " + o.studyDir);
    // The fly-over alone keeps its fields; the review adds its own.
    ASSERT_TRUE(cov.contains("flyover"));
    const double alone = cov["flyover"]["both_cameras"]["fraction"].get<double>();
    ASSERT_TRUE(cov.contains("flyover_with_review") && cov["flyover_with_review"].is_object());
    const json& withReview = cov["flyover_with_review"];
    const double reviewed = withReview["fraction"].get<double>();
    std::printf("small phantom, coverage 32 px every 60 mm: fly-over %.4f, with %d review views %.4f\n", alone,
                cov["review_views"].get<int>(), reviewed);
    EXPECT_GE(reviewed, alone);
    EXPECT_EQ(withReview["target"].get<double>(), 0.995);
    EXPECT_EQ(withReview["target_reached"].get<bool>(), reviewed >= 0.995);
    for (const json& r : withReview["missed_regions"]) {
        EXPECT_TRUE(r.contains("area_mm2") && r.contains("centroid_mm") && r.contains("arc_mm"));
        ASSERT_TRUE(r.contains("reason"));
        EXPECT_FALSE(r["reason"].get<std::string>().empty());
    }
    EXPECT_EQ(withReview["missed_regions"].size(), withReview["missed_regions_count"].get<std::size_t>());

    // Views 60 mm apart miss plenty: the review has work to do.
    EXPECT_LT(alone, 0.995);
    const int views = cov["review_views"].get<int>();
    EXPECT_GT(views, 0);
    const json poses = readJson((study / "review/poses.json").string());
    EXPECT_EQ(poses["world_frame"], "LPS");
    ASSERT_EQ(poses["views"].size(), std::size_t(views));
    for (const json& v : poses["views"]) {
        EXPECT_TRUE(fs::is_regular_file(study / "review" / v["file"].get<std::string>())) << v["file"];
        const std::string kind = v["kind"].get<std::string>();
        const std::size_t cams = v["cameras"].size();
        EXPECT_EQ(cams, kind.find("_pair") != std::string::npos ? 2u : 1u) << kind;
        EXPECT_GT(v["added_area_mm2"].get<double>(), 0.0);
        EXPECT_TRUE(v.contains("arc_mm") && v.contains("roll_deg") && v["cameras"][0].contains("position_mm"));
    }
    EXPECT_EQ(cov["review"]["views"].get<int>(), views);
}

TEST_F(ReviewStage, OffLeavesAnEmptyReviewAndNoCoverageWithReview)
{
    RunOptions o = options("review-off");
    o.params.render.flythroughFrames = false;
    o.params.render.review = false;
    runPipeline(o);
    const fs::path study = o.studyDir;
    const json cov = readJson((study / "coverage/coverage.json").string());
    EXPECT_TRUE(cov["flyover_with_review"].is_null());
    EXPECT_EQ(cov["review_views"].get<int>(), 0);
    const json poses = readJson((study / "review/poses.json").string());
    EXPECT_FALSE(poses["enabled"].get<bool>());
    EXPECT_TRUE(poses["views"].empty());
    std::size_t files = 0;
    for (const auto& e : fs::directory_iterator(study / "review")) files += e.is_regular_file();
    EXPECT_EQ(files, 1u) << "only poses.json";
}

} // namespace
} // namespace flyover::test
