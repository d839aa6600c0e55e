#include "colon/report.h"

#include "colon/anatomy_segments.h"
#include "pipeline/atomic_write.h"
#include "pipeline/json_io.h"
#include "pipeline/staged_folder.h"
#include "volume/error.h"
#include "volume/image.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

std::string percent(double fraction)
{
    std::ostringstream o;
    o.setf(std::ios::fixed);
    o.precision(1);
    o << fraction * 100 << " %";
    return o.str();
}

std::string mm(double v)
{
    std::ostringstream o;
    o.setf(std::ios::fixed);
    o.precision(1);
    o << v << " mm";
    return o.str();
}

double fractionOf(const json& method, const std::string& source, const char* what)
{
    if (!method.is_object() || !method.contains("fraction") || !method["fraction"].is_number())
        throw InputError(source + ": " + what + " has no \"fraction\"");
    return method["fraction"].get<double>();
}

/// The files of a candidate's images that exist in polyps/, as study-relative paths.
json imagesOf(const PolypCandidate* c, const fs::path& studyDir)
{
    json images = json::object();
    if (!c) return images;
    for (const auto& [kind, file] : c->images)
        if (fs::is_regular_file(studyDir / "polyps" / file)) images[kind] = "polyps/" + file;
    return images;
}

} // namespace

ExamAdequacy assessExam(const json& coverage, const std::string& source, const ReportRules& rules)
{
    if (!coverage.is_object() || coverage.value("schema", "") != "flyover.coverage/1")
        throw InputError(source + ": not a coverage file (schema \"flyover.coverage/1\" expected)");
    ExamAdequacy e;
    if (!coverage.contains("flyover") || !coverage["flyover"].is_object())
        throw InputError(source + ": no \"flyover\" section");
    e.flyover = fractionOf(coverage["flyover"].value("both_cameras", json()), source, "flyover.both_cameras");
    const json withReview = coverage.value("flyover_with_review", json());
    e.reviewed = withReview.is_object();
    e.withReview = e.reviewed ? fractionOf(withReview, source, "flyover_with_review") : e.flyover;
    if (e.withReview < rules.minCoverageWithReview)
        e.reasons.push_back("coverage " + std::string(e.reviewed ? "with review " : "(no review views) ") +
                            percent(e.withReview) + " is below " + percent(rules.minCoverageWithReview));
    const json segments = coverage.value("segments", json());
    if (!segments.is_array()) {
        e.reasons.push_back("no per-segment coverage in " + source + " (the centerline has no anatomical segments)");
    } else {
        for (const std::string& name : anatomySegmentNames()) {
            const auto it = std::find_if(segments.begin(), segments.end(),
                                         [&](const json& s) { return s.is_object() && s.value("segment", "") == name; });
            if (it == segments.end()) {
                e.segments.push_back(json{{"segment", name}, {"area_mm2", 0}, {"flyover", 0},
                                          {"flyover_with_review", 0}, {"seen", false}, {"on_path", false}});
                e.reasons.push_back("segment " + name + " is not on the path (not found or not reached)");
                continue;
            }
            const double alone = it->value("flyover", 0.0);
            const double reviewed = it->value("flyover_with_review", alone);
            const bool seen = reviewed >= rules.segmentSeenMin && it->value("area_mm2", 0.0) > 0;
            e.segments.push_back(json{{"segment", name}, {"area_mm2", it->value("area_mm2", 0.0)}, {"flyover", alone},
                                      {"flyover_with_review", reviewed}, {"seen", seen}, {"on_path", true}});
            if (!seen)
                e.reasons.push_back("segment " + name + " not seen: " + percent(reviewed) + " of its wall with review (" +
                                    percent(rules.segmentSeenMin) + " needed)");
        }
    }
    e.adequate = e.reasons.empty();
    return e;
}

CRads classifyCRads(const ExamAdequacy& exam, const std::vector<ReportPolyp>& polyps, const ReportRules& rules)
{
    if (!exam.adequate)
        return {"C0", "inadequate study: " + exam.reasons.front() +
                          (exam.reasons.size() > 1 ? " (and " + std::to_string(exam.reasons.size() - 1) + " more)" : "")};
    double largest = 0;
    int small = 0;
    for (const ReportPolyp& p : polyps) {
        largest = std::max(largest, p.sizeMm);
        if (p.sizeMm >= rules.reportMinMm && p.sizeMm < rules.largeMm) ++small;
    }
    if (largest >= rules.massMm)
        return {"C4", "a likely malignant mass: a polyp of " + mm(largest) + " (rule: size >= " + mm(rules.massMm) + ")"};
    if (largest >= rules.largeMm) return {"C3", "a polyp of " + mm(largest) + " (>= " + mm(rules.largeMm) + ")"};
    if (small >= 3) return {"C3", std::to_string(small) + " polyps of 6-9 mm (three or more)"};
    if (small >= 1) return {"C2", std::to_string(small) + (small == 1 ? " polyp" : " polyps") + " of 6-9 mm"};
    return {"C1", "no polyp of 6 mm or more"};
}

namespace {

json entryOfFinding(const Finding& f, const PolypCandidate* c, const fs::path& dir)
{
    json e{{"id", f.id},
           {"source", f.source},
           {"candidate_id", f.source == "candidate" ? json(f.candidateId) : json(nullptr)},
           {"segment", f.segment},
           {"size_mm", f.sizeMm},
           {"morphology", f.morphology},
           {"arc_mm", f.arcMm},
           {"position_mm", vec3Json(f.positionMm)},
           {"note", f.note},
           {"score", c ? json(c->score) : json(nullptr)},
           {"images", imagesOf(c, dir)}};
    return e;
}

json entryOfCandidate(const PolypCandidate& c, const fs::path& dir)
{
    return json{{"id", c.id},
                {"source", "candidate"},
                {"candidate_id", c.id},
                {"segment", c.segment},
                {"size_mm", c.sizeMm},
                {"morphology", c.morphology},
                {"arc_mm", c.arcMm},
                {"position_mm", vec3Json(c.centroidMm)},
                {"note", ""},
                {"score", c.score},
                {"images", imagesOf(&c, dir)}};
}

json rulesJson(const ReportRules& r)
{
    return json::array({"size: a polyp's largest dimension without its stalk (Zalis et al., Radiology 2005)",
                        "C0: inadequate study: an anatomical segment with less than " + percent(r.segmentSeenMin) +
                            " of its wall seen with review, or coverage with review below " +
                            percent(r.minCoverageWithReview),
                        "C1: no polyp of " + mm(r.reportMinMm) + " or more",
                        "C2: one or two polyps of 6-9 mm",
                        "C3: a polyp of " + mm(r.largeMm) + " or more, or three or more of 6-9 mm",
                        "C4: a likely malignant mass; here a polyp of " + mm(r.massMm) +
                            " or more (morphology is the reader's to judge)",
                        "E (extracolonic): to be filled by the reader"});
}

json examJson(const ExamAdequacy& e, const json& coverage, const ReportRules& rules)
{
    return json{{"adequate", e.adequate},
                {"coverage_flyover", e.flyover},
                {"coverage_with_review", e.withReview},
                {"reviewed", e.reviewed},
                {"review_views", coverage.value("review_views", 0)},
                {"min_coverage_with_review", rules.minCoverageWithReview},
                {"segment_seen_min", rules.segmentSeenMin},
                {"segments", e.segments},
                {"reasons", e.reasons},
                {"coverage_file", "coverage/coverage.json"}};
}

} // namespace

json buildReport(const std::string& studyDir, const ReportRules& rules)
{
    const fs::path dir(studyDir);
    if (!fs::is_directory(dir)) throw InputError(studyDir + ": no such study folder");
    const fs::path coverageFile = dir / "coverage" / "coverage.json";
    if (!fs::exists(coverageFile))
        throw InputError(studyDir + ": no coverage/coverage.json: the coverage stage has not run (make it with: "
                                    "flyover stage render --study " + studyDir + ")");
    const json coverage = readJson(coverageFile.string());
    const ExamAdequacy exam = assessExam(coverage, coverageFile.string(), rules);

    const fs::path findingsFile = dir / "findings.json";
    const std::vector<Finding> findings = fs::exists(findingsFile) ? readFindings(findingsFile.string())
                                                                   : std::vector<Finding>{};
    const bool draft = findings.empty();
    const fs::path candidatesFile = dir / "polyps" / "candidates.json";
    std::vector<PolypCandidate> candidates;
    if (fs::exists(candidatesFile)) candidates = readCandidates(candidatesFile.string());
    else if (draft)
        throw InputError(studyDir + ": no polyps/candidates.json and no findings.json: the polyps stage has not run "
                                    "(make it with: flyover stage polyps --study " + studyDir + ")");
    auto candidate = [&](const std::string& id) -> const PolypCandidate* {
        for (const auto& c : candidates)
            if (c.id == id) return &c;
        return nullptr;
    };

    json entries = json::array();
    std::vector<ReportPolyp> counted;
    int accepted = 0, rejected = 0;
    if (draft) {
        for (const PolypCandidate& c : candidates)
            if (c.sizeMm >= rules.reportMinMm) entries.push_back(entryOfCandidate(c, dir));
    } else {
        for (const Finding& f : findings) {
            if (f.status != "accepted") {
                ++rejected;
                continue;
            }
            ++accepted;
            entries.push_back(entryOfFinding(f, f.source == "candidate" ? candidate(f.candidateId) : nullptr, dir));
        }
    }
    std::stable_sort(entries.begin(), entries.end(),
                     [](const json& a, const json& b) { return a["arc_mm"].get<double>() < b["arc_mm"].get<double>(); });
    for (json& e : entries) {
        const double size = e["size_mm"].get<double>();
        e["counted"] = size >= rules.reportMinMm;
        if (size >= rules.reportMinMm) counted.push_back(ReportPolyp{size});
    }
    const CRads cr = classifyCRads(exam, counted, rules);
    return json{{"schema", "flyover.report/1"},
                {"world_frame", WORLD_FRAME},
                {"study", fs::absolute(dir).lexically_normal().filename().string()},
                {"c_rads", cr.category},
                {"c_rads_reason", cr.reason},
                {"c_rads_rules", rulesJson(rules)},
                {"e_rads", nullptr},
                {"e_rads_note", "to be filled by the reader"},
                {"draft", draft},
                {"draft_reason", draft ? json("no finding reviewed yet: the candidates of " + mm(rules.reportMinMm) +
                                              " or more, not a reader's findings")
                                       : json(nullptr)},
                {"exam", examJson(exam, coverage, rules)},
                {"findings", entries},
                {"review", {{"candidates", candidates.size()},
                            {"findings_accepted", accepted},
                            {"findings_rejected", rejected},
                            {"findings_file", fs::exists(findingsFile) ? json("findings.json") : json(nullptr)}}}};
}

json writeReport(const std::string& studyDir, const ReportRules& rules)
{
    const json report = buildReport(studyDir, rules);
    const std::string html = reportHtml(report, studyDir);
    StagedFolder folder(fs::path(studyDir), "report");
    writeJson(folder.path("report.json"), report);
    writeAtomically(folder.path("report.html"), [&](const std::string& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out << html;
        if (!out.flush()) throw InputError(folder.path("report.html") + ": cannot write");
    });
    folder.commit();
    return report;
}

} // namespace flyover
