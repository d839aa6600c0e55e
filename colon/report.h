/// @file report.h
/// @brief `flyover report`: the exam's C-RADS report from a study's coverage, candidates and
///        findings, as report/report.json (flyover.report/1) and a self-contained, printable
///        report/report.html.
///
/// C-RADS colonic categories (Zalis et al., Radiology 2005), a polyp's size being its largest
/// dimension without the stalk:
///   C0 inadequate study: an anatomical segment not seen, or coverage with review below 90 %;
///   C1 no polyp >= 6 mm;  C2 one or two polyps of 6-9 mm;
///   C3 a polyp >= 10 mm, or three or more of 6-9 mm;
///   C4 a likely malignant mass: here, a polyp >= 30 mm (the reader judges morphology).
/// The extracolonic E category is left to the reader. The findings the reader accepted make the
/// report; before any is reviewed it is a draft from the candidates >= 6 mm.
#pragma once

#include "colon/findings.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace flyover {

/// The thresholds of the rules above.
struct ReportRules {
    double minCoverageWithReview = 0.90;  ///< C0 below this
    double segmentSeenMin = 0.5;          ///< a segment with less of its wall seen (with review) is "not seen"
    double reportMinMm = 6.0;             ///< smaller polyps are not reported (C-RADS)
    double largeMm = 10.0;                ///< C3 from this size
    double massMm = 30.0;                 ///< C4 from this size
};

/// One polyp the category counts.
struct ReportPolyp {
    double sizeMm = 0;
};

/// Whether the exam was adequate, from coverage.json, and why not.
struct ExamAdequacy {
    bool adequate = true;
    double flyover = 0;            ///< fly-over coverage alone
    double withReview = 0;         ///< with the review views (the fly-over's own when review was off)
    bool reviewed = false;         ///< coverage.json has flyover_with_review
    nlohmann::json segments = nlohmann::json::array();  ///< per segment, with "seen"
    std::vector<std::string> reasons;                   ///< why inadequate (empty when adequate)
};

/// Reads the exam's adequacy from a coverage.json document.
/// @throw InputError naming `source` when a needed field is missing.
ExamAdequacy assessExam(const nlohmann::json& coverage, const std::string& source, const ReportRules& rules = {});

/// The C-RADS category ("C0".."C4") and one sentence saying which rule gave it.
struct CRads {
    std::string category;
    std::string reason;
};
CRads classifyCRads(const ExamAdequacy& exam, const std::vector<ReportPolyp>& polyps, const ReportRules& rules = {});

/// Builds the report document of the study in `studyDir` (reads coverage/coverage.json,
/// polyps/candidates.json, findings.json). @throw InputError with one line naming the missing
/// stage and the command that makes it.
nlohmann::json buildReport(const std::string& studyDir, const ReportRules& rules = {});

/// The report as a self-contained HTML page (images embedded as data: URIs, no external URL),
/// printable on A4; a draft says so on every printed page.
std::string reportHtml(const nlohmann::json& report, const std::string& studyDir);

/// Writes STUDY/report/ (report.json, report.html) atomically: a staged folder renamed into
/// place. @return the report document.
nlohmann::json writeReport(const std::string& studyDir, const ReportRules& rules = {});

} // namespace flyover
