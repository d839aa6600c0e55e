// The real colon in shared/ (EdinGCA_3D_00020: one piece, loops lying against each other):
// segment from the mask, cut the contacts, one path from the anus end to the cecum, compared
// with the published reference path. Skipped when the data is absent.
#include "tests/volume/shared_data.h"
#include "colon/centerline.h"
#include "colon/contacts.h"
#include "volume/image_io.h"
#include "colon/lumen_mask.h"
#include "colon/path_compare.h"
#include "colon/segment.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <vector>

namespace fs = std::filesystem;

namespace flyover {
namespace {

TEST(RealColonContacts, GcaPathRunsAnusToCecumWithoutShortcut)
{
    const std::string shared = test::sharedDataDir();
    const std::string dir = shared + "/real/gca-colon-00020";
    const std::string maskPath = dir + "/large_intestine.nii.gz";
    if (shared.empty() || !fs::exists(maskPath) || !fs::exists(dir + "/reference_path.json"))
        GTEST_SKIP() << test::sharedDataLookedFor("real/gca-colon-00020/{large_intestine.nii.gz,reference_path.json}");
    std::ifstream refFile(dir + "/reference_path.json");
    const nlohmann::json ref = nlohmann::json::parse(refFile);
    std::vector<Vec3d> refPts;
    for (const auto& p : ref.at("position_mm")) refPts.push_back({p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()});
    const auto& lm = ref.at("landmarks");
    const double valveArc = lm.at("ileocaecal_valve_caecum").at("arc_mm").get<double>();

    const auto t0 = std::chrono::steady_clock::now();
    SegmentParams sp;
    LumenSegmentation seg;
    {
        auto source = openImage(maskPath);
        seg = segmentFromMask(*source, sp);
    }
    const auto t1 = std::chrono::steady_clock::now();
    const ContactReport contacts = cutContacts(*seg.sdf, seg.mask.get(), sp.contacts);
    const auto t2 = std::chrono::steady_clock::now();
    CenterlineReport cr;
    const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{}, nullptr, &cr);
    const auto t3 = std::chrono::steady_clock::now();
    ASSERT_GE(cl.points.size(), 100u);

    // Each path point -> the nearest reference point: error and reference arc.
    std::vector<Vec3d> pathPts;
    for (const CenterlinePoint& p : cl.points) pathPts.push_back(p.positionMm);
    const PathComparison cmp = comparePathToReference(pathPts, refPts);
    const std::vector<double>& err = cmp.errorMm;
    const std::vector<double>& arc = cmp.referenceArcMm;
    const double mean = cmp.meanErrorMm, p95 = cmp.p95ErrorMm, worstJump = cmp.worstJumpMm;
    // Length against the reference from the anus to where our path ends along it.
    const double refLength = arc.back() - arc.front();
    std::size_t cut = 0;
    for (const ContactInfo& c : contacts.contacts) {
        cut += c.cut;
        std::cout << "    contact at (" << c.positionMm.x << ", " << c.positionMm.y << ", " << c.positionMm.z
                  << ") width " << c.widthMm << " sides " << c.sideRadiusMm[0] << "/" << c.sideRadiusMm[1]
                  << " straight " << c.straightMm << " detour " << c.detourMm << " removed "
                  << c.voxelsRemoved << (c.cut ? " cut" : " kept") << "\n";
    }
    std::cout << "[ gca-00020 ] segment " << std::chrono::duration<double>(t1 - t0).count() << " s, contacts "
              << std::chrono::duration<double>(t2 - t1).count() << " s (" << contacts.regions << " regions, "
              << contacts.cycleLinks << " cycle links, " << cut << " cut), centerline "
              << std::chrono::duration<double>(t3 - t2).count() << " s; path " << cl.lengthMm()
              << " mm, reference anus -> path end " << refLength << " mm (ratio " << cl.lengthMm() / refLength
              << "), path ends at reference arc " << arc.back() << " mm (ileocaecal valve " << valveArc
              << " mm); error to reference mean " << mean << " p95 " << p95 << " mm; largest jump "
              << worstJump << " mm; starts " << err.front() << " mm from reference arc " << arc.front()
              << " mm; " << cr.nearWall.size() << " near-wall stretches, " << cr.bridges.size() << " bridges\n";

    EXPECT_LT(arc.front(), 30.0) << "the path starts at the anus end of the reference";
    EXPECT_GT(arc.back(), valveArc - 100.0) << "the path ends in the cecum";
    EXPECT_NEAR(cl.lengthMm() / refLength, 1.0, 0.05) << "path length vs the reference over the same stretch";
    // The target is 20 mm. The jumps of 38.4 and 22.7 mm that the path had (centerline
    // version 4) were no contact: the section centring pulled the path onto the tip of the fold
    // inside two flexures folded back on themselves (below the hepatic flexure, and near the
    // cecum) while the ridge of D went round it 17 mm away (colon/centerline.cpp,
    // keepRidgeWhereShallow). Since the fix the largest jump is 10.9 mm (in
    // the transverse colon, reference arc 1747 -> 1758 mm); bound 16 mm.
    EXPECT_LE(worstJump, 16.0) << "consecutive path points jump along the reference: a shortcut";
    EXPECT_LE(mean, 5.0) << "mean distance to the reference path (mm)";
    // No kinks: the fly-over cameras must not spin.
    std::cout << "[ gca-00020 ] turns: largest step " << cr.maxTurnDeg << " deg (" << cr.turnsOver30
              << " over 30), largest normal step " << cr.maxNormalStepDeg << " deg (" << cr.normalStepsOver15
              << " over 15); " << cr.leftOut.size() << " regions of lumen off the path\n";
    for (const LeftOutLumen& r : cr.leftOut) std::cout << "    left out: " << r.reason << "\n";
    EXPECT_EQ(cr.turnsOver30, 0) << "steps turning more than 30 degrees (largest " << cr.maxTurnDeg << ")";
    EXPECT_EQ(cr.normalStepsOver15, 0) << "camera normal steps over 15 degrees (largest " << cr.maxNormalStepDeg << ")";
    // Ends: within 30 mm of the anus and 40 mm of the appendix orifice (or beyond it, in the cecum).
    const auto refPoint = [&](const char* name) {
        const auto& p = ref.at("position_mm").at(lm.at(name).at("index").get<std::size_t>());
        return Vec3d{p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()};
    };
    EXPECT_LT(distance(cl.points.front().positionMm, refPoint("anus")), 30.0) << "the path starts far from the anus";
    EXPECT_LT(distance(cl.points.back().positionMm, refPoint("appendix_orifice")), 40.0)
        << "the path ends far from the appendix orifice";
}

} // namespace
} // namespace flyover
