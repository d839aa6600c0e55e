// Anatomical segments and landmarks on the centerline (colon/anatomy_segments.h): against the
// phantoms' truth segments (several seeds, sizes and colons, on paths traced from the truth
// mask), on paths whose frame is unknown or mirrored, on the real colon in shared/ against its
// published landmarks, the seen share per segment, and the fields in centerline.json.
#include "colon/anatomy_segments.h"

#include "colon/centerline.h"
#include "colon/contacts.h"
#include "colon/lumen_mask.h"
#include "colon/phantom.h"
#include "colon/segment.h"
#include "pipeline/artifact_io.h"
#include "tests/colon/truth_arc.h"
#include "tests/volume/shared_data.h"
#include "volume/error.h"
#include "volume/image_io.h"
#include "volume/scan_orientation.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include <unistd.h>

namespace fs = std::filesystem;

namespace flyover {
namespace {

/// A flexure label is right where the truth names either segment it joins (the phantom's
/// truth has no flexure segments: its descending colon meets the transverse colon at the
/// splenic flexure, the transverse meets the ascending at the hepatic).
bool labelMatchesTruth(const std::string& label, const std::string& truth)
{
    if (label == truth) return true;
    if (label == "splenic_flexure") return truth == "descending" || truth == "transverse";
    if (label == "hepatic_flexure") return truth == "transverse" || truth == "ascending";
    return false;
}

/// Share of the path's length (uniform steps: of its points) whose label is right against the
/// truth segment of the nearest truth centerline sample.
double labelAccuracy(const std::vector<Vec3d>& path, const std::vector<std::string>& labels, const PhantomTruth& truth)
{
    if (path.empty()) return 0;
    std::size_t right = 0;
    for (std::size_t i = 0; i < path.size(); ++i) {
        const std::size_t t = std::size_t(test::nearestArcMm(truth.centerlineMm, path[i]));
        right += labelMatchesTruth(labels[i], truth.segment[t]);
    }
    return double(right) / double(path.size());
}

Centerline centerlineThrough(const std::vector<Vec3d>& positions, double stepMm = 1.0)
{
    Centerline c;
    c.stepMm = stepMm;
    for (const Vec3d& p : positions) {
        CenterlinePoint q;
        q.positionMm = p;
        c.points.push_back(q);
    }
    return c;
}

std::vector<Vec3d> positionsOf(const Centerline& c)
{
    std::vector<Vec3d> out;
    for (const CenterlinePoint& p : c.points) out.push_back(p.positionMm);
    return out;
}

std::string describeLandmarks(const AnatomySegments& a)
{
    std::string out;
    char line[160];
    for (const CenterlineLandmark& l : a.landmarks) {
        std::snprintf(line, sizeof line, " %s at arc %.0f (%.0f, %.0f, %.0f);", l.name.c_str(), l.arcMm,
                      l.positionMm.x, l.positionMm.y, l.positionMm.z);
        out += line;
    }
    return out;
}

const CenterlineLandmark* findLandmark(const std::vector<CenterlineLandmark>& ls, const std::string& name)
{
    for (const CenterlineLandmark& l : ls)
        if (l.name == name) return &l;
    return nullptr;
}

// ---- Phantoms -------------------------------------------------------------------------------

constexpr double MIN_ACCURACY = 0.90;

/// The phantom's truth mask -> segment -> contacts -> centerline -> segments, against the truth.
double tracedPhantomAccuracy(const PhantomParams& pp, const std::string& label)
{
    const Phantom ph = makePhantom(pp);
    Image3<float> image;
    image.geometry = ph.truthLumen.geometry;
    image.voxels.assign(ph.truthLumen.voxels.begin(), ph.truthLumen.voxels.end());
    LumenSegmentation seg = segmentFromMask(image, SegmentParams{});
    cutContacts(*seg.sdf, seg.mask.get(), ContactParams{});
    const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{});
    if (cl.points.size() < 100) {
        ADD_FAILURE() << label << ": no path traced";
        return 0;
    }
    const AnatomySegments a = labelAnatomySegments(cl, PatientFrame::Stated);
    EXPECT_EQ(a.frame, "patient") << label << ": " << a.frameReason;
    EXPECT_EQ(a.landmarks.size(), 5u) << label;
    const double acc = labelAccuracy(positionsOf(cl), a.segment, ph.truth);
    std::printf("[ measure  ] segments %s: %.1f%% of %.0f mm labelled right (frame %s);%s\n", label.c_str(),
                100.0 * acc, cl.lengthMm(), a.frame.c_str(), describeLandmarks(a).c_str());
    return acc;
}

PhantomParams phantomParams(uint64_t seed, PhantomSize size)
{
    PhantomParams p;
    p.seed = seed;
    p.size = size;
    return p;
}

TEST(AnatomySegmentsPhantom, TracedPathsLabelledRightSmallSeeds)
{
    for (uint64_t seed : {1u, 2u, 3u})
        EXPECT_GE(tracedPhantomAccuracy(phantomParams(seed, PhantomSize::Small), "small seed " + std::to_string(seed)),
                  MIN_ACCURACY);
}

TEST(AnatomySegmentsPhantom, TracedPathLabelledRightMedium)
{
    EXPECT_GE(tracedPhantomAccuracy(phantomParams(4, PhantomSize::Medium), "medium seed 4"), MIN_ACCURACY);
}

TEST(AnatomySegmentsPhantom, TracedPathLabelledRightFull)
{
    EXPECT_GE(tracedPhantomAccuracy(phantomParams(8, PhantomSize::Full), "full seed 8"), MIN_ACCURACY);
}

TEST(AnatomySegmentsPhantom, TracedPathLabelledRightAcrossCollapsedSigmoid)
{
    PhantomParams collapsed = phantomParams(9, PhantomSize::Small);
    collapsed.collapse = true;
    EXPECT_GE(tracedPhantomAccuracy(collapsed, "small collapsed seed 9"), MIN_ACCURACY);
}

TEST(AnatomySegmentsPhantom, TracedPathsLabelledRightRedundantAndTouching)
{
    PhantomParams redundant = phantomParams(5, PhantomSize::Small);
    redundant.redundant = true;
    EXPECT_GE(tracedPhantomAccuracy(redundant, "small redundant seed 5"), MIN_ACCURACY);
    PhantomParams touching = phantomParams(6, PhantomSize::Small);
    touching.touching = 2;
    EXPECT_GE(tracedPhantomAccuracy(touching, "small touching 2 seed 6"), MIN_ACCURACY);
}

/// The truth paths themselves (every colon variant), in the patient frame, with the frame
/// unknown and turned (the world's axes permuted and mirrored), and with left and right
/// mirrored while the frame is said to be the patient's.
TEST(AnatomySegmentsPhantom, TruthPathsInEveryFrame)
{
    struct Variant {
        const char* name;
        bool redundant;
        int touching;
    };
    for (const Variant v : {Variant{"default", false, 0}, Variant{"redundant", true, 0}, Variant{"touching 2", false, 2}}) {
        PhantomParams p = phantomParams(7, PhantomSize::Small);
        p.redundant = v.redundant;
        p.touching = v.touching;
        const PhantomTruth truth = makePhantom(p).truth;
        const std::vector<Vec3d>& path = truth.centerlineMm;

        const AnatomySegments stated = labelAnatomySegments(centerlineThrough(path), PatientFrame::Stated);
        EXPECT_EQ(stated.frame, "patient") << v.name;
        const double accStated = labelAccuracy(path, stated.segment, truth);
        EXPECT_GE(accStated, MIN_ACCURACY) << v.name;

        // Unknown frame: world (x, y, z) holds the patient's (superior, -left, posterior).
        std::vector<Vec3d> turned;
        for (const Vec3d& q : path) turned.push_back({q.z, -q.x, q.y});
        const AnatomySegments unknown = labelAnatomySegments(centerlineThrough(turned), PatientFrame::Unknown);
        EXPECT_EQ(unknown.frame, "path only") << v.name;
        EXPECT_FALSE(unknown.frameReason.empty());
        EXPECT_NEAR(unknown.axes.superior.x, 1.0, 1e-12) << v.name << ": superior is world +x here";
        EXPECT_NEAR(unknown.axes.left.y, -1.0, 1e-12) << v.name << ": left is world -y here";
        const double accUnknown = labelAccuracy(path, unknown.segment, truth);
        EXPECT_GE(accUnknown, MIN_ACCURACY) << v.name;

        // Stated frame but left and right mirrored (a header that gets x wrong).
        std::vector<Vec3d> mirrored;
        for (const Vec3d& q : path) mirrored.push_back({-q.x, q.y, q.z});
        const AnatomySegments flipped = labelAnatomySegments(centerlineThrough(mirrored), PatientFrame::Stated);
        EXPECT_EQ(flipped.frame, "path only") << v.name << ": the descending colon on the right";
        EXPECT_NE(flipped.frameReason.find("mirrored"), std::string::npos) << flipped.frameReason;
        const double accMirrored = labelAccuracy(path, flipped.segment, truth);
        EXPECT_GE(accMirrored, MIN_ACCURACY) << v.name;
        std::printf("[ measure  ] segments on the %s truth path: %.1f%% stated, %.1f%% unknown frame, %.1f%% mirrored;%s\n",
                    v.name, 100.0 * accStated, 100.0 * accUnknown, 100.0 * accMirrored,
                    describeLandmarks(stated).c_str());
    }
}

// ---- Steps on simple paths --------------------------------------------------------------------

/// A colon frame drawn with straight runs (LPS mm): rectum up the middle, sigmoid to the left
/// and down, descending up the left flank, transverse across, ascending down the right.
std::vector<Vec3d> boxColon()
{
    const std::vector<Vec3d> corners{{0, 40, -150}, {0, 40, -30},  {40, 0, -40},  {100, 20, -120},
                                     {110, 30, -100}, {110, 30, 80}, {0, -60, 40}, {-110, 30, 70},
                                     {-110, 30, -120}};
    std::vector<Vec3d> out;
    for (std::size_t k = 1; k < corners.size(); ++k) {
        const Vec3d a = corners[k - 1], b = corners[k];
        const int steps = int(distance(a, b));
        for (int s = 0; s < steps; ++s) out.push_back(a + (b - a) * (double(s) / steps));
    }
    out.push_back(corners.back());
    return out;
}

TEST(AnatomySegments, StepsOnABoxColon)
{
    const std::vector<Vec3d> path = boxColon();
    const BodyAxes axes = bodyAxesFromPatientFrame();
    const AnatomySegmentParams params;
    ASSERT_TRUE(pathRunsLeftBeforeRight(path, axes));
    const Flexures f = findFlexures(path, axes, params);
    ASSERT_TRUE(f.found);
    EXPECT_LT(distance(path[f.splenic], {110, 30, 80}), 3.0);
    EXPECT_LT(distance(path[f.hepatic], {-110, 30, 70}), 3.0);
    const std::size_t ds = findDescendingSigmoidJunction(path, axes, f.splenic, params);
    EXPECT_LT(distance(path[ds], {100, 20, -120}), 3.0) << "the lowest point of the left limb";
    const std::size_t rs = findRectosigmoidJunction(path, axes, 1.0, ds, params);
    EXPECT_NEAR(path[rs].z, -30.0, 15.0) << "where the rectum stops rising (its chord over 20 mm levels off)";
    const std::size_t cecum = findCecumStart(path.size(), 1.0, f.hepatic, params);
    EXPECT_EQ(cecum, path.size() - 1 - 60);

    const AnatomySegments a = labelAnatomySegments(centerlineThrough(path), PatientFrame::Stated);
    ASSERT_EQ(a.segment.size(), path.size());
    std::vector<std::string> order;
    for (const std::string& s : a.segment)
        if (order.empty() || order.back() != s) order.push_back(s);
    EXPECT_EQ(order, anatomySegmentNames()) << "every segment once, in path order";
    ASSERT_EQ(a.landmarks.size(), 5u);
    EXPECT_EQ(a.landmarks[0].name, "rectosigmoid_junction");
    EXPECT_EQ(a.landmarks[4].name, "cecum");
    for (const CenterlineLandmark& l : a.landmarks) {
        EXPECT_DOUBLE_EQ(l.arcMm, double(l.index));
        EXPECT_EQ(l.positionMm, path[l.index]);
    }
}

TEST(AnatomySegments, UnknownFrameIsLabelledFromThePathAlone)
{
    // The box colon stored with the patient's superior along world -y and left along +z.
    std::vector<Vec3d> turned;
    for (const Vec3d& q : boxColon()) turned.push_back({q.y, -q.z, q.x});
    const AnatomySegments a = labelAnatomySegments(centerlineThrough(turned), PatientFrame::Unknown);
    EXPECT_EQ(a.frame, "path only");
    EXPECT_EQ(a.axes.superior, (Vec3d{0, -1, 0}));
    EXPECT_EQ(a.axes.left, (Vec3d{0, 0, 1}));
    const AnatomySegments inFrame = labelAnatomySegments(centerlineThrough(boxColon()), PatientFrame::Stated);
    EXPECT_EQ(inFrame.frame, "patient");
    EXPECT_EQ(a.segment, inFrame.segment) << "the same labels whichever way the path is stored";
}

TEST(AnatomySegments, ShortOrOpenPathsStillGetALabelPerPoint)
{
    EXPECT_TRUE(labelAnatomySegments(Centerline{}, PatientFrame::Stated).segment.empty());
    std::vector<Vec3d> straight;
    for (int i = 0; i < 300; ++i) straight.push_back({0, 0, double(i)});
    const AnatomySegments a = labelAnatomySegments(centerlineThrough(straight), PatientFrame::Stated);
    ASSERT_EQ(a.segment.size(), straight.size());
    EXPECT_EQ(a.segment.front(), "rectum");
}

// ---- Seen share per segment -------------------------------------------------------------------

TEST(AnatomySegments, SeenSharePerSegment)
{
    const std::vector<std::string> seg{"rectum", "rectum", "sigmoid", "sigmoid", "cecum"};
    const std::vector<uint8_t> seen{1, 0, 1, 1, 0, 1, 1};
    const std::vector<double> area{2.0, 3.0, 1.0, 4.0, 5.0, 7.0, 100.0};
    const std::vector<std::size_t> nearest{0, 1, 2, 3, 3, 4, NOT_ON_PATH};
    const std::vector<SegmentSeenShare> s = segmentSeenShares(seen, area, nearest, seg);
    ASSERT_EQ(s.size(), 3u);
    EXPECT_EQ(s[0].segment, "rectum");
    EXPECT_DOUBLE_EQ(s[0].areaMm2, 5.0);
    EXPECT_DOUBLE_EQ(s[0].seenAreaMm2, 2.0);
    EXPECT_DOUBLE_EQ(s[0].fraction, 0.4);
    EXPECT_EQ(s[1].segment, "sigmoid");
    EXPECT_DOUBLE_EQ(s[1].areaMm2, 10.0);
    EXPECT_DOUBLE_EQ(s[1].seenAreaMm2, 5.0);
    EXPECT_EQ(s[2].segment, "cecum");
    EXPECT_DOUBLE_EQ(s[2].fraction, 1.0) << "the left-out triangle is not counted";
    // A segment named on the path with no wall near it: listed with area 0.
    const std::vector<SegmentSeenShare> empty = segmentSeenShares({}, {}, {}, seg);
    ASSERT_EQ(empty.size(), 3u);
    EXPECT_EQ(empty[2].fraction, 0.0);
    EXPECT_THROW(segmentSeenShares({1}, {1.0, 2.0}, {0}, seg), std::invalid_argument);
    EXPECT_THROW(segmentSeenShares({1}, {1.0}, {5}, seg), std::invalid_argument);
}

// ---- centerline.json --------------------------------------------------------------------------

TEST(AnatomySegments, WrittenToAndReadFromCenterlineJson)
{
    Centerline c = centerlineThrough(boxColon());
    computeTangentsAndNormals(c);
    const nlohmann::json before = centerlineToJson(c);
    EXPECT_FALSE(before.contains("segment")) << "an unlabelled path writes no segment fields";
    const Centerline old = centerlineFromJson(before, "old.json");
    EXPECT_TRUE(old.segment.empty());
    EXPECT_TRUE(old.landmarks.empty());

    addAnatomySegments(c, PatientFrame::Stated);
    const nlohmann::json j = centerlineToJson(c);
    ASSERT_TRUE(j.contains("segment"));
    EXPECT_EQ(j.at("segment").size(), c.points.size());
    EXPECT_EQ(j.at("segments_frame"), "patient");
    ASSERT_TRUE(j.at("landmarks").contains("splenic_flexure"));
    EXPECT_EQ(j.at("landmarks").at("splenic_flexure").at("position_mm").size(), 3u);
    const Centerline back = centerlineFromJson(j, "new.json");
    EXPECT_EQ(back.segment, c.segment);
    EXPECT_EQ(back.segmentsFrame, "patient");
    ASSERT_EQ(back.landmarks.size(), c.landmarks.size());
    for (std::size_t k = 0; k < c.landmarks.size(); ++k) {
        EXPECT_EQ(back.landmarks[k].name, c.landmarks[k].name) << "path order kept";
        EXPECT_EQ(back.landmarks[k].index, c.landmarks[k].index);
        EXPECT_NEAR(distance(back.landmarks[k].positionMm, c.landmarks[k].positionMm), 0.0, 1e-9);
    }
    nlohmann::json bad = j;
    bad["segment"].erase(0);
    EXPECT_THROW(centerlineFromJson(bad, "bad.json"), InputError);
    bad = j;
    bad["landmarks"]["cecum"]["index"] = c.points.size();
    EXPECT_THROW(centerlineFromJson(bad, "bad.json"), InputError);
}

// ---- Whether a header states the orientation -------------------------------------------------

TEST(AnatomySegments, HeadersWithoutOrientationAreTold)
{
    const fs::path dir = fs::temp_directory_path() / ("flyover_orient_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    Image3<uint8_t> mask;
    mask.geometry.size = {4, 4, 4};
    mask.voxels.assign(64, 1);
    const std::string stated = (dir / "stated.nii").string();
    writeImage(mask, stated);
    EXPECT_TRUE(scanStatesOrientation(stated));
    writeImage(mask, (dir / "stated.nii.gz").string());
    EXPECT_TRUE(scanStatesOrientation((dir / "stated.nii.gz").string()));
    // The same file with qform_code and sform_code 0 (bytes 252-255 of a NIfTI-1 header).
    std::string bytes;
    {
        std::ifstream in(stated, std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    ASSERT_GT(bytes.size(), 352u);
    bytes.replace(252, 4, std::string(4, '\0'));
    const std::string bare = (dir / "bare.nii").string();
    std::ofstream(bare, std::ios::binary) << bytes;
    EXPECT_FALSE(scanStatesOrientation(bare));
    std::ofstream(dir / "space.nhdr") << "NRRD0004\ntype: uchar\ndimension: 3\nspace: left-posterior-superior\n"
                                         "sizes: 4 4 4\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\n";
    EXPECT_TRUE(scanStatesOrientation((dir / "space.nhdr").string()));
    std::ofstream(dir / "plain.nhdr") << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nspacings: 1 1 1\n\n";
    EXPECT_FALSE(scanStatesOrientation((dir / "plain.nhdr").string()));
    fs::remove_all(dir);
}

// ---- The real colon -----------------------------------------------------------------------------

/// Our landmarks against gca-colon-00020's published ones (Euclidean distance, mm).
struct RealDistances {
    double descendingSigmoid = 1e9, splenic = 1e9, hepatic = 1e9, cecumToValve = 1e9;
};

RealDistances compareToReference(const AnatomySegments& a, const nlohmann::json& ref)
{
    const auto refPoint = [&](const char* name) {
        const auto& p = ref.at("position_mm").at(ref.at("landmarks").at(name).at("index").get<std::size_t>());
        return Vec3d{p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()};
    };
    RealDistances d;
    if (const auto* l = findLandmark(a.landmarks, "descending_sigmoid_junction"))
        d.descendingSigmoid = distance(l->positionMm, refPoint("descending_sigmoid_junction"));
    if (const auto* l = findLandmark(a.landmarks, "splenic_flexure"))
        d.splenic = distance(l->positionMm, refPoint("splenic_flexure"));
    if (const auto* l = findLandmark(a.landmarks, "hepatic_flexure"))
        d.hepatic = distance(l->positionMm, refPoint("hepatic_flexure"));
    if (const auto* l = findLandmark(a.landmarks, "cecum"))
        d.cecumToValve = distance(l->positionMm, refPoint("ileocaecal_valve_caecum"));
    return d;
}

void expectNearReference(const RealDistances& d, const std::string& what)
{
    std::printf("[ gca-00020 ] %s: descending-sigmoid junction %.1f mm, splenic flexure %.1f mm, hepatic flexure "
                "%.1f mm from the published landmarks; our cecum start %.1f mm from the ileocaecal valve\n",
                what.c_str(), d.descendingSigmoid, d.splenic, d.hepatic, d.cecumToValve);
    EXPECT_LE(d.descendingSigmoid, 50.0) << what;
    EXPECT_LE(d.splenic, 50.0) << what;
    EXPECT_LE(d.hepatic, 50.0) << what;
}

TEST(RealColonSegments, GcaLandmarksWithin50MmOfThePublishedOnes)
{
    const std::string shared = test::sharedDataDir();
    const std::string dir = shared + "/real/gca-colon-00020";
    const std::string maskPath = dir + "/large_intestine.nii.gz";
    if (shared.empty() || !fs::exists(maskPath) || !fs::exists(dir + "/reference_path.json"))
        GTEST_SKIP() << test::sharedDataLookedFor("real/gca-colon-00020/{large_intestine.nii.gz,reference_path.json}");
    std::ifstream refFile(dir + "/reference_path.json");
    const nlohmann::json ref = nlohmann::json::parse(refFile);

    // The published path itself (0.5 mm apart, near enough uniform).
    std::vector<Vec3d> refPts;
    for (const auto& p : ref.at("position_mm")) refPts.push_back({p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()});
    const double refStep = ref.at("landmarks").at("appendix_tip").at("arc_mm").get<double>() / double(refPts.size() - 1);
    const AnatomySegments onRef = labelAnatomySegments(centerlineThrough(refPts, refStep), PatientFrame::Stated);
    std::printf("[ gca-00020 ] published path: frame %s (%s);%s\n", onRef.frame.c_str(), onRef.frameReason.c_str(),
                describeLandmarks(onRef).c_str());
    expectNearReference(compareToReference(onRef, ref), "on the published path");

    // Our path, traced from the mask as the pipeline does.
    LumenSegmentation seg;
    {
        auto source = openImage(maskPath);
        seg = segmentFromMask(*source, SegmentParams{});
    }
    cutContacts(*seg.sdf, seg.mask.get(), SegmentParams{}.contacts);
    const Centerline cl = extractCenterline(*seg.sdf, CenterlineParams{});
    ASSERT_GE(cl.points.size(), 100u);
    const AnatomySegments a = labelAnatomySegments(cl, PatientFrame::Stated);
    std::printf("[ gca-00020 ] traced path %.0f mm: frame %s (%s);%s\n", cl.lengthMm(), a.frame.c_str(),
                a.frameReason.c_str(), describeLandmarks(a).c_str());
    ASSERT_EQ(a.landmarks.size(), 5u);
    expectNearReference(compareToReference(a, ref), "on the traced path");
}

} // namespace
} // namespace flyover
