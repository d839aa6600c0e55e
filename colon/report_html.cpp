// report.html: the report document (colon/report.h) as one self-contained page. Every image is
// embedded as a data: URI and the page names no external address, so it opens and prints the
// same anywhere, offline; a draft carries a banner and a watermark that print on every page.

#include "colon/report.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

std::string base64(const std::string& bytes)
{
    static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    out.reserve((bytes.size() + 2) / 3 * 4);
    std::size_t i = 0;
    for (; i + 2 < bytes.size(); i += 3) {
        const unsigned v = (unsigned char)bytes[i] << 16 | (unsigned char)bytes[i + 1] << 8 | (unsigned char)bytes[i + 2];
        out += table[v >> 18 & 63], out += table[v >> 12 & 63], out += table[v >> 6 & 63], out += table[v & 63];
    }
    if (i + 1 == bytes.size()) {
        const unsigned v = (unsigned char)bytes[i] << 16;
        out += table[v >> 18 & 63], out += table[v >> 12 & 63], out += "==";
    } else if (i + 2 == bytes.size()) {
        const unsigned v = (unsigned char)bytes[i] << 16 | (unsigned char)bytes[i + 1] << 8;
        out += table[v >> 18 & 63], out += table[v >> 12 & 63], out += table[v >> 6 & 63], out += '=';
    }
    return out;
}

/// Text for HTML: markup characters escaped, and '/' and ':' too, so that no text (a note)
/// can form an address.
std::string esc(const std::string& s)
{
    std::string out;
    for (char c : s) {
        switch (c) {
        case '&': out += "&amp;"; break;
        case '<': out += "&lt;"; break;
        case '>': out += "&gt;"; break;
        case '"': out += "&quot;"; break;
        case '\'': out += "&#39;"; break;
        case '/': out += "&#47;"; break;
        case ':': out += "&#58;"; break;
        default: out += c;
        }
    }
    return out;
}

std::string fixed(double v, int digits)
{
    std::ostringstream o;
    o.setf(std::ios::fixed);
    o.precision(digits);
    o << v;
    return o.str();
}

std::string pct(const json& v) { return v.is_number() ? fixed(v.get<double>() * 100, 1) + " %" : "n&#47;a"; }
std::string str(const json& j, const char* k) { return j.contains(k) && j[k].is_string() ? j[k].get<std::string>() : ""; }
std::string segmentName(const std::string& s)
{
    std::string out = s.empty() ? "unknown" : s;
    for (char& c : out)
        if (c == '_') c = ' ';
    return out;
}

/// A data: URI of an image file of the study, or "" when it cannot be read.
std::string dataUri(const fs::path& file)
{
    std::string ext = file.extension().string();
    for (char& c : ext) c = char(std::tolower((unsigned char)c));
    const char* mime = ext == ".png" ? "image/png" : (ext == ".jpg" || ext == ".jpeg") ? "image/jpeg" : nullptr;
    if (!mime || !fs::is_regular_file(file) || fs::file_size(file) > (64u << 20)) return "";
    std::ifstream in(file, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), {});
    if (!in.good() && !in.eof()) return "";
    return std::string("data:") + mime + ";base64," + base64(bytes);
}

const char* STYLE = R"css(
@page { size: A4; margin: 16mm 14mm 18mm 14mm; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", Arial, sans-serif; font-size: 10.5pt; color: #111; margin: 0 auto;
       max-width: 190mm; line-height: 1.35; background: #fff; }
h1 { font-size: 17pt; margin: 0 0 2mm 0; }
h2 { font-size: 12.5pt; border-bottom: 1px solid #999; margin: 6mm 0 2mm 0; padding-bottom: 1mm; }
table { border-collapse: collapse; width: 100%; margin: 1mm 0 2mm 0; }
th, td { text-align: left; padding: 1mm 2mm; border-bottom: 1px solid #ddd; vertical-align: top; }
th { background: #f0f0f0; font-weight: 600; }
td.num, th.num { text-align: right; }
.category { font-size: 26pt; font-weight: 700; margin: 0; }
.summary { display: flex; gap: 8mm; align-items: baseline; }
.bad { color: #a00000; font-weight: 600; }
.muted { color: #555; }
.finding { border: 1px solid #bbb; padding: 2mm 3mm; margin: 3mm 0; }
.finding h3 { margin: 0 0 1mm 0; font-size: 11pt; }
.images { display: flex; flex-wrap: wrap; gap: 2mm; }
.images figure { margin: 0; }
.images img { display: block; max-height: 45mm; max-width: 88mm; border: 1px solid #999; }
.images figcaption { font-size: 8.5pt; color: #444; }
.fill { display: inline-block; min-width: 60mm; border-bottom: 1px solid #333; }
.draft-banner { position: fixed; top: 0; left: 0; right: 0; background: #ffe9a8; color: #6b3d00;
                text-align: center; font-weight: 700; padding: 1.5mm; border-bottom: 1px solid #c90; z-index: 2; }
.draft-mark { position: fixed; top: 45%; left: 0; right: 0; text-align: center; font-size: 110pt; font-weight: 800;
              color: rgba(200, 0, 0, 0.10); transform: rotate(-30deg); pointer-events: none; z-index: 1; }
body.draft main { padding-top: 10mm; }
footer { margin-top: 8mm; font-size: 8.5pt; color: #555; }
@media print {
  body { max-width: none; }
  h2 { break-after: avoid; }
  .finding, tr, figure { break-inside: avoid; }
  .draft-banner, .draft-mark { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
}
)css";

void examSection(std::ostringstream& h, const json& exam)
{
    h << "<section><h2>Exam</h2><table><tr><th>coverage of the wall</th><th class=\"num\">share</th></tr>"
      << "<tr><td>fly-over alone</td><td class=\"num\">" << pct(exam["coverage_flyover"]) << "</td></tr>"
      << "<tr><td>" << (exam.value("reviewed", false) ? "with review views" : "with review (no review views: the fly-over&#39;s)")
      << "</td><td class=\"num\">" << pct(exam["coverage_with_review"]) << "</td></tr></table>";
    h << "<p>Adequacy: " << (exam.value("adequate", false) ? "adequate" : "<span class=\"bad\">inadequate</span>")
      << " (needs " << pct(exam["min_coverage_with_review"]) << " with review and every segment seen).</p>";
    if (!exam["reasons"].empty()) {
        h << "<ul>";
        for (const auto& r : exam["reasons"]) h << "<li class=\"bad\">" << esc(r.get<std::string>()) << "</li>";
        h << "</ul>";
    }
    h << "<table><tr><th>segment</th><th class=\"num\">wall (cm&sup2;)</th><th class=\"num\">fly-over</th>"
      << "<th class=\"num\">with review</th><th>seen</th></tr>";
    for (const auto& s : exam["segments"]) {
        const bool seen = s.value("seen", false);
        h << "<tr><td>" << esc(segmentName(str(s, "segment"))) << "</td><td class=\"num\">"
          << fixed(s.value("area_mm2", 0.0) / 100.0, 1) << "</td><td class=\"num\">" << pct(s["flyover"])
          << "</td><td class=\"num\">" << pct(s["flyover_with_review"]) << "</td><td"
          << (seen ? ">yes" : " class=\"bad\">no") << (s.value("on_path", true) ? "" : " (not on the path)")
          << "</td></tr>";
    }
    h << "</table></section>";
}

void findingArticle(std::ostringstream& h, const json& f, std::size_t number, const fs::path& studyDir)
{
    const std::string source = str(f, "source") == "hand" ? "added by hand" : "candidate " + str(f, "candidate_id");
    h << "<article class=\"finding\"><h3>" << number << ". " << esc(segmentName(str(f, "segment"))) << ", "
      << fixed(f.value("size_mm", 0.0), 1) << " mm, " << esc(str(f, "morphology")) << "</h3>"
      << "<table><tr><th>size (largest, without stalk)</th><th>morphology</th><th>segment</th>"
      << "<th class=\"num\">from the rectum</th><th>position (LPS mm)</th><th>source</th></tr><tr><td>"
      << fixed(f.value("size_mm", 0.0), 1) << " mm" << (f.value("counted", true) ? "" : " (below 6 mm: not counted)")
      << "</td><td>" << esc(str(f, "morphology")) << "</td><td>" << esc(segmentName(str(f, "segment")))
      << "</td><td class=\"num\">" << fixed(f.value("arc_mm", 0.0) / 10.0, 1) << " cm</td><td>";
    const json& p = f["position_mm"];
    if (p.is_array() && p.size() == 3)
        h << fixed(p[0].get<double>(), 1) << ", " << fixed(p[1].get<double>(), 1) << ", " << fixed(p[2].get<double>(), 1);
    h << "</td><td>" << esc(source);
    if (f.contains("score") && f["score"].is_number()) h << " (score " << fixed(f["score"].get<double>(), 2) << ")";
    h << "</td></tr></table>";
    if (!str(f, "note").empty()) h << "<p>Note: " << esc(str(f, "note")) << "</p>";
    const json& images = f["images"];
    if (images.is_object() && !images.empty()) {
        h << "<div class=\"images\">";
        std::vector<std::string> kinds = {"pair", "axial", "coronal", "sagittal"};
        for (auto it = images.begin(); it != images.end(); ++it)
            if (std::find(kinds.begin(), kinds.end(), it.key()) == kinds.end()) kinds.push_back(it.key());
        for (const std::string& kind : kinds) {
            if (!images.contains(kind) || !images[kind].is_string()) continue;
            const std::string uri = dataUri(studyDir / images[kind].get<std::string>());
            if (uri.empty()) continue;
            h << "<figure><img src=\"" << uri << "\" alt=\"" << esc(kind) << " view of finding " << number
              << "\"><figcaption>" << esc(kind == "pair" ? "fly-over pair" : "CT " + kind) << "</figcaption></figure>";
        }
        h << "</div>";
    }
    h << "</article>";
}

} // namespace

std::string reportHtml(const json& report, const std::string& studyDir)
{
    const bool draft = report.value("draft", true);
    std::ostringstream h;
    h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
      << "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
      << "<title>CT colonography report: " << esc(str(report, "study")) << (draft ? " (DRAFT)" : "") << "</title>"
      << "<style>" << STYLE << "</style></head>\n<body" << (draft ? " class=\"draft\"" : "") << ">\n";
    if (draft)
        h << "<div class=\"draft-banner\" id=\"draft-banner\">DRAFT: " << esc(str(report, "draft_reason"))
          << "</div><div class=\"draft-mark\" aria-hidden=\"true\">DRAFT</div>\n";
    h << "<main><header><h1>CT colonography report</h1><p class=\"muted\">Study " << esc(str(report, "study"))
      << ". Virtual fly-over with one-sided transparency; positions in LPS mm, distances along the colon "
         "from the rectum.</p></header>\n";
    h << "<section><h2>Classification (C-RADS)</h2><div class=\"summary\"><p class=\"category\" id=\"c-rads\">"
      << esc(str(report, "c_rads")) << "</p><p>" << esc(str(report, "c_rads_reason")) << "</p></div>"
      << "<p>Extracolonic (E category): <span class=\"fill\">to be filled by the reader</span></p></section>\n";
    examSection(h, report["exam"]);
    const json& findings = report["findings"];
    h << "\n<section><h2>" << (draft ? "Candidates of 6 mm or more (not reviewed)" : "Findings") << "</h2>";
    if (findings.empty()) h << "<p>" << (draft ? "No candidate of 6 mm or more." : "No finding accepted.") << "</p>";
    std::size_t n = 0;
    for (const auto& f : findings) findingArticle(h, f, ++n, fs::path(studyDir));
    h << "</section>\n<section><h2>Rules</h2><ul>";
    for (const auto& r : report["c_rads_rules"]) h << "<li>" << esc(r.get<std::string>()) << "</li>";
    h << "</ul></section>\n<footer>Written by flyover report from coverage&#47;coverage.json, "
      << "polyps&#47;candidates.json and findings.json. A decision aid: the reader signs the report.</footer>"
      << "</main>\n</body></html>\n";
    return h.str();
}

} // namespace flyover
