// flyover report and the findings files: C-RADS on hand-written study folders (coverage.json,
// candidates.json, findings.json fixtures), the draft, strict reading, the self-contained HTML,
// and the command line's refusals.

#include "colon/findings.h"
#include "colon/report.h"
#include "pipeline/json_io.h"
#include "pipeline/png_io.h"
#include "volume/error.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sys/wait.h>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace flyover;

namespace {

const std::vector<std::string> SEGMENTS = {"rectum",     "sigmoid",         "descending", "splenic_flexure",
                                           "transverse", "hepatic_flexure", "ascending",  "cecum"};

/// A study folder holding what the report reads, written by hand.
class StudyFixture {
public:
    explicit StudyFixture(const std::string& name)
        : dir(fs::temp_directory_path() / ("flyover_report_" + name + "_" + std::to_string(::getpid())))
    {
        fs::remove_all(dir);
        fs::create_directories(dir / "coverage");
        fs::create_directories(dir / "polyps");
    }
    ~StudyFixture() { fs::remove_all(dir); }

    /// coverage.json: `withReview` overall; each segment 0.97 seen but those in `unseen` (0.1),
    /// and those in `absent` left out.
    void coverage(double withReview, const std::set<std::string>& unseen = {}, const std::set<std::string>& absent = {})
    {
        json segs = json::array();
        for (const auto& s : SEGMENTS) {
            if (absent.count(s)) continue;
            const double f = unseen.count(s) ? 0.1 : 0.97;
            segs.push_back(json{{"segment", s}, {"area_mm2", 12000.0}, {"flyover", f - 0.02}, {"flyover_with_review", f}});
        }
        json method{{"fraction", withReview - 0.03}, {"seen_area_mm2", 1}, {"missed_regions", json::array()}};
        json reviewed{{"fraction", withReview}, {"target", 0.99}, {"target_reached", false}};
        writeJson((dir / "coverage" / "coverage.json").string(),
                  json{{"schema", "flyover.coverage/1"},
                       {"world_frame", "LPS"},
                       {"flyover", {{"both_cameras", method}}},
                       {"flyover_with_review", reviewed},
                       {"review_views", 4},
                       {"segments", segs}});
    }

    /// candidates.json with candidates of these sizes (c1, c2, ...), c1 with images.
    void candidates(const std::vector<double>& sizes)
    {
        json list = json::array();
        for (std::size_t k = 0; k < sizes.size(); ++k) {
            json c{{"id", "c" + std::to_string(k + 1)},
                   {"centroid_mm", {10.0 * double(k), -5.0, 100.0}},
                   {"size_mm", sizes[k]},
                   {"height_mm", sizes[k] / 2},
                   {"volume_mm3", sizes[k] * sizes[k] * sizes[k] / 3},
                   {"morphology", "sessile"},
                   {"arc_mm", 100.0 + 50.0 * double(k)},
                   {"segment", SEGMENTS[k % SEGMENTS.size()]},
                   {"score", 0.9 - 0.1 * double(k)},
                   {"pose", nullptr}};
            if (k == 0) c["images"] = json{{"pair", "c1_pair.png"}, {"axial", "c1_axial.png"}, {"coronal", "gone.png"}};
            list.push_back(c);
        }
        RgbImage img;
        img.width = 8;
        img.height = 4;
        img.rgb.assign(8 * 4 * 3, 200);
        writePng((dir / "polyps" / "c1_pair.png").string(), img);
        writePng((dir / "polyps" / "c1_axial.png").string(), img);
        writeJson((dir / "polyps" / "candidates.json").string(),
                  json{{"schema", "flyover.polyps/1"}, {"world_frame", "LPS"}, {"candidates", list}});
    }

    Finding finding(const std::string& id, const std::string& candidate, double size, const std::string& status)
    {
        Finding f;
        f.id = id;
        f.source = candidate.empty() ? "hand" : "candidate";
        f.candidateId = candidate;
        f.status = status;
        f.sizeMm = size;
        f.positionMm = Vec3d{1, 2, 3};
        f.arcMm = 300;
        f.segment = "transverse";
        f.morphology = "flat";
        return f;
    }

    std::string path(const std::string& rel) const { return (dir / rel).string(); }
    std::string slurp(const std::string& rel) const
    {
        std::ifstream in(dir / rel, std::ios::binary);
        return std::string((std::istreambuf_iterator<char>(in)), {});
    }

    fs::path dir;
};

/// Runs the flyover binary; returns the exit code, stderr in `err`.
int runFlyover(const std::string& args, std::string& err)
{
    const std::string errFile = (fs::temp_directory_path() / ("flyover_report_err_" + std::to_string(::getpid()))).string();
    const int status = std::system((std::string(FLYOVER_BIN) + " --quiet " + args + " 2>" + errFile).c_str());
    std::ifstream in(errFile);
    err.assign((std::istreambuf_iterator<char>(in)), {});
    fs::remove(errFile);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

} // namespace

TEST(Report, AcceptedTwelveMillimetreFindingIsC3)
{
    StudyFixture s("c3");
    s.coverage(0.96);
    s.candidates({12.0, 4.0});
    writeFindings(s.path("findings.json"), {s.finding("f1", "c1", 12.0, "accepted"), s.finding("f2", "c2", 4.0, "rejected")});
    const json r = writeReport(s.dir.string());
    EXPECT_EQ(r["c_rads"], "C3");
    EXPECT_FALSE(r["draft"].get<bool>());
    EXPECT_TRUE(r["e_rads"].is_null());
    ASSERT_EQ(r["findings"].size(), 1u);
    EXPECT_EQ(r["findings"][0]["images"]["pair"], "polyps/c1_pair.png");
    EXPECT_FALSE(r["findings"][0]["images"].contains("coronal"));  // absent file tolerated
    EXPECT_TRUE(r["exam"]["adequate"].get<bool>());
    EXPECT_EQ(r["exam"]["segments"].size(), SEGMENTS.size());
    // the files are in place and say the same
    EXPECT_EQ(readJson(s.path("report/report.json")), r);
    const std::string html = s.slurp("report/report.html");
    EXPECT_NE(html.find("data:image/png;base64,"), std::string::npos);
    EXPECT_EQ(html.find("DRAFT"), std::string::npos);
    EXPECT_NE(html.find("to be filled by the reader"), std::string::npos);
}

TEST(Report, OnlySevenMillimetreIsC2AndThreeAreC3)
{
    StudyFixture s("c2");
    s.coverage(0.95);
    s.candidates({7.0});
    writeFindings(s.path("findings.json"), {s.finding("f1", "c1", 7.0, "accepted")});
    EXPECT_EQ(buildReport(s.dir.string())["c_rads"], "C2");
    writeFindings(s.path("findings.json"), {s.finding("f1", "c1", 7.0, "accepted"), s.finding("f2", "", 8.0, "accepted"),
                                            s.finding("f3", "", 6.5, "accepted")});
    EXPECT_EQ(buildReport(s.dir.string())["c_rads"], "C3");
}

TEST(Report, NoPolypIsC1AndAMassIsC4)
{
    StudyFixture s("c1");
    s.coverage(0.95);
    s.candidates({12.0});
    writeFindings(s.path("findings.json"), {s.finding("f1", "c1", 12.0, "rejected"), s.finding("f2", "", 3.0, "accepted")});
    const json r = buildReport(s.dir.string());
    EXPECT_EQ(r["c_rads"], "C1");
    EXPECT_FALSE(r["draft"].get<bool>());
    ASSERT_EQ(r["findings"].size(), 1u);
    EXPECT_FALSE(r["findings"][0]["counted"].get<bool>());
    writeFindings(s.path("findings.json"), {s.finding("f1", "", 31.0, "accepted")});
    const json m = buildReport(s.dir.string());
    EXPECT_EQ(m["c_rads"], "C4");
    EXPECT_NE(m["c_rads_reason"].get<std::string>().find("30"), std::string::npos);
}

TEST(Report, UnseenSegmentOrLowCoverageIsC0)
{
    StudyFixture s("c0");
    s.candidates({12.0});
    writeFindings(s.path("findings.json"), {s.finding("f1", "c1", 12.0, "accepted")});
    s.coverage(0.95, {"splenic_flexure"});
    json r = buildReport(s.dir.string());
    EXPECT_EQ(r["c_rads"], "C0");
    EXPECT_FALSE(r["exam"]["adequate"].get<bool>());
    EXPECT_NE(r["c_rads_reason"].get<std::string>().find("splenic_flexure"), std::string::npos);
    s.coverage(0.95, {}, {"cecum"});
    EXPECT_EQ(buildReport(s.dir.string())["c_rads"], "C0");
    s.coverage(0.85);
    r = buildReport(s.dir.string());
    EXPECT_EQ(r["c_rads"], "C0");
    EXPECT_NE(r["c_rads_reason"].get<std::string>().find("90"), std::string::npos);
}

TEST(Report, DraftFromCandidatesWhenNothingReviewed)
{
    StudyFixture s("draft");
    s.coverage(0.95);
    s.candidates({8.0, 5.0, 7.0});
    const json r = writeReport(s.dir.string());
    EXPECT_TRUE(r["draft"].get<bool>());
    EXPECT_EQ(r["findings"].size(), 2u);  // the 5 mm candidate is left out
    EXPECT_EQ(r["c_rads"], "C2");
    const std::string html = s.slurp("report/report.html");
    EXPECT_NE(html.find("class=\"draft-banner\""), std::string::npos);
    EXPECT_NE(html.find("position: fixed"), std::string::npos);  // prints on every page
    EXPECT_NE(html.find("@page { size: A4"), std::string::npos);
    // an empty findings.json is "nothing reviewed" too
    writeFindings(s.path("findings.json"), {});
    EXPECT_TRUE(buildReport(s.dir.string())["draft"].get<bool>());
}

TEST(Report, HtmlNamesNoExternalAddress)
{
    StudyFixture s("urls");
    s.coverage(0.95);
    s.candidates({12.0});
    Finding f = s.finding("f1", "c1", 12.0, "accepted");
    f.note = "see https://example.org/x and //host/y <script>";
    writeFindings(s.path("findings.json"), {f});
    writeReport(s.dir.string());
    std::string html = s.slurp("report/report.html");
    // every src= is a data: URI ...
    const std::regex src(R"(src\s*=\s*["']?([^"'\s>]*))", std::regex::icase);
    int images = 0;
    for (auto it = std::sregex_iterator(html.begin(), html.end(), src); it != std::sregex_iterator(); ++it, ++images)
        EXPECT_EQ((*it)[1].str().rfind("data:", 0), 0u) << (*it)[1].str().substr(0, 60);
    EXPECT_EQ(images, 2);
    // ... and with the data: URIs taken out, no address is left
    html = std::regex_replace(html, std::regex(R"(data:[^"'\s)]*)"), "");
    EXPECT_FALSE(std::regex_search(html, std::regex("https?:", std::regex::icase)));
    EXPECT_EQ(html.find("//"), std::string::npos);
    EXPECT_EQ(html.find("<script"), std::string::npos);
    EXPECT_FALSE(std::regex_search(html, std::regex(R"(url\s*\()", std::regex::icase)));
}

TEST(Report, CorruptFindingsRefusedAndLeftAlone)
{
    StudyFixture s("corrupt");
    s.coverage(0.95);
    s.candidates({12.0});
    const std::string bad = "{\"schema\": \"flyover.findings/1\", \"findings\": [{\"id\": \"f1\", \"status\": \"maybe\"";
    for (const std::string& text :
         {bad, std::string("{\"schema\": \"flyover.findings/1\", \"findings\": [{\"id\": \"f1\", \"source\": \"hand\", "
                           "\"status\": \"maybe\", \"size_mm\": 5, \"position_mm\": [0,0,0], \"arc_mm\": 1, "
                           "\"segment\": \"cecum\", \"morphology\": \"flat\"}]}")}) {
        { std::ofstream(s.path("findings.json"), std::ios::binary) << text; }
        try {
            writeReport(s.dir.string());
            ADD_FAILURE() << "a corrupt findings.json was accepted";
        } catch (const InputError& e) {
            const std::string what = e.what();
            EXPECT_NE(what.find("findings.json"), std::string::npos) << what;
            EXPECT_EQ(what.find('\n'), std::string::npos);
        }
        EXPECT_EQ(s.slurp("findings.json"), text);
        EXPECT_FALSE(fs::exists(s.path("report")));
    }
    std::string err;
    EXPECT_EQ(runFlyover("report --study " + s.dir.string(), err), 1);
    EXPECT_NE(err.find("findings.json"), std::string::npos) << err;
}

TEST(Report, MissingStageNamedAndUnknownOptionRefused)
{
    StudyFixture s("missing");
    std::string err;
    EXPECT_EQ(runFlyover("report --study " + s.dir.string(), err), 1);
    EXPECT_NE(err.find("coverage"), std::string::npos) << err;
    EXPECT_NE(err.find("flyover stage render"), std::string::npos) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    s.coverage(0.95);
    EXPECT_EQ(runFlyover("report --study " + s.dir.string(), err), 1);
    EXPECT_NE(err.find("polyps"), std::string::npos) << err;
    EXPECT_NE(err.find("flyover stage polyps"), std::string::npos) << err;
    EXPECT_EQ(runFlyover("report --study " + s.dir.string() + " --bogus", err), 2);
    EXPECT_NE(err.find("bogus"), std::string::npos) << err;
    s.candidates({7.0});
    EXPECT_EQ(runFlyover("report --study " + s.dir.string(), err), 0) << err;
    EXPECT_TRUE(fs::exists(s.path("report/report.html")));
}

TEST(Findings, RoundTripAndStrictReading)
{
    StudyFixture s("roundtrip");
    Finding f = s.finding("f7", "c3", 9.5, "accepted");
    f.note = "near the fold";
    Finding h = s.finding("f8", "", 4.0, "rejected");
    writeFindings(s.path("findings.json"), {f, h});
    const auto back = readFindings(s.path("findings.json"));
    ASSERT_EQ(back.size(), 2u);
    EXPECT_EQ(back[0].candidateId, "c3");
    EXPECT_EQ(back[0].note, "near the fold");
    EXPECT_EQ(back[1].source, "hand");
    EXPECT_DOUBLE_EQ(back[0].sizeMm, 9.5);
    json j = findingsFileJson({f, f});
    writeJson(s.path("findings.json"), j);
    EXPECT_THROW(readFindings(s.path("findings.json")), InputError);  // the same id twice
    j = findingsFileJson({f});
    j["findings"][0]["colour"] = "red";
    writeJson(s.path("findings.json"), j);
    EXPECT_THROW(readFindings(s.path("findings.json")), InputError);  // an unknown field
    j = findingsFileJson({f});
    j["schema"] = "flyover.bookmarks/1";
    writeJson(s.path("findings.json"), j);
    EXPECT_THROW(readFindings(s.path("findings.json")), InputError);
}
