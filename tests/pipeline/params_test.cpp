#include "colon/params.h"
#include "volume/error.h"

#include <gtest/gtest.h>

using namespace flyover;

TEST(Params, DefaultsRoundTripThroughJson)
{
    PipelineParams a;
    for (const auto& stage : stageNames()) {
        PipelineParams b;
        b.render.widthPx = 7;  // make sure the round trip overwrites
        applyParamsJson(b, nlohmann::json{{stage, stageParamsToJson(a, stage)}}, "test");
        EXPECT_EQ(stageParamsToJson(a, stage), stageParamsToJson(b, stage)) << "stage " << stage;
    }
}

TEST(Params, UnknownParameterIsRejectedByName)
{
    PipelineParams p;
    try {
        applyParamAssignment(p, "segment.air_treshold_hu=-700");
        FAIL() << "a misspelt parameter was accepted";
    } catch (const ParameterError& e) {
        EXPECT_NE(std::string(e.what()).find("segment.air_treshold_hu"), std::string::npos) << e.what();
    }
    EXPECT_THROW(applyParamAssignment(p, "segmnt.step_mm=1"), ParameterError);
    EXPECT_THROW(applyParamsJson(p, nlohmann::json{{"render", {{"fov", 60}}}}, "cfg.json"), ParameterError);
}

TEST(Params, AssignmentsParseTypedValues)
{
    PipelineParams p;
    applyParamAssignment(p, "segment.air_threshold_hu=-700");
    applyParamAssignment(p, "render.direction=left");
    applyParamAssignment(p, "render.ost=false");
    applyParamAssignment(p, "centerline.rectum_mm=1.5,-2,30");
    EXPECT_DOUBLE_EQ(p.segment.airThresholdHu, -700);
    EXPECT_EQ(p.render.direction, "left");
    EXPECT_FALSE(p.render.ost);
    ASSERT_TRUE(p.centerline.rectumMm.has_value());
    EXPECT_DOUBLE_EQ(p.centerline.rectumMm->x, 1.5);
    EXPECT_DOUBLE_EQ(p.centerline.rectumMm->z, 30);
    EXPECT_THROW(applyParamAssignment(p, "render.width_px=wide"), ParameterError);
    EXPECT_THROW(applyParamAssignment(p, "render.width_px=1.5"), ParameterError);
    EXPECT_THROW(applyParamAssignment(p, "render.ost"), ParameterError);
}

TEST(Params, ValidationNamesTheParameter)
{
    PipelineParams p;
    p.render.fovDeg = 200;
    try {
        validateParams(p);
        FAIL() << "fov 200 accepted";
    } catch (const ParameterError& e) {
        EXPECT_NE(std::string(e.what()).find("render.fov_deg"), std::string::npos) << e.what();
    }
    p = {};
    p.render.direction = "up";
    EXPECT_THROW(validateParams(p), ParameterError);
    p = {};
    EXPECT_NO_THROW(validateParams(p));
}

TEST(Params, ReviewParametersParseAndValidate)
{
    PipelineParams p;
    EXPECT_TRUE(p.render.review);
    EXPECT_DOUBLE_EQ(p.render.reviewTarget, 0.995);
    applyParamAssignment(p, "render.review=false");
    applyParamAssignment(p, "render.review_target=0.98");
    EXPECT_FALSE(p.render.review);
    EXPECT_DOUBLE_EQ(p.render.reviewTarget, 0.98);
    EXPECT_NO_THROW(validateParams(p));
    EXPECT_THROW(applyParamAssignment(p, "render.review=maybe"), ParameterError);
    for (const double bad : {0.0, -0.5, 1.01}) {
        p.render.reviewTarget = bad;
        try {
            validateParams(p);
            FAIL() << "render.review_target " << bad << " accepted";
        } catch (const ParameterError& e) {
            EXPECT_NE(std::string(e.what()).find("render.review_target"), std::string::npos) << e.what();
        }
    }
}
