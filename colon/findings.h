/// @file findings.h
/// @brief The reader's findings and the polyps stage's candidates, as files of a study.
///
/// `polyps/candidates.json` (flyover.polyps/1, written by the polyps stage) lists candidate
/// polyps, best score first. `findings.json` (flyover.findings/1, written by the viewer) holds
/// what the reader made of them: each candidate accepted or rejected (with an edited size), and
/// findings added by hand. Both are read strictly: a damaged file is refused with one line
/// naming it, and findings.json is then never overwritten (move it away to start afresh).
/// `flyover run` leaves findings.json alone, so it survives re-runs.
#pragma once

#include "volume/vec3.h"

#include <nlohmann/json.hpp>

#include <map>
#include <optional>
#include <string>
#include <vector>

namespace flyover {

/// The morphologies a candidate or finding may have.
bool isMorphology(const std::string& m);
/// The anatomical segment names (colon/anatomy_segments.h) or "" (unknown).
bool isSegmentName(const std::string& s);

/// One candidate of polyps/candidates.json.
struct PolypCandidate {
    std::string id;  ///< "c1", ...
    Vec3d centroidMm;
    double sizeMm = 0, heightMm = 0, volumeMm3 = 0;
    std::string morphology;  ///< sessile | pedunculated | flat
    double arcMm = 0;
    std::string segment;
    double score = 0;                    ///< 0..1
    std::optional<double> huMean;
    nlohmann::json pose;                 ///< the camera JSON, or null
    std::map<std::string, std::string> images;  ///< "pair", "axial", ... -> file name in polyps/
};

/// One finding of findings.json.
struct Finding {
    std::string id;           ///< "f1", ...
    std::string source;       ///< "candidate" or "hand"
    std::string candidateId;  ///< with source "candidate"
    std::string status;       ///< "accepted" or "rejected"
    double sizeMm = 0;        ///< the edited size, else the candidate's
    Vec3d positionMm;
    double arcMm = 0;
    std::string segment;
    std::string morphology;
    std::string note;
};

/// Reads polyps/candidates.json. @throw InputError naming the file and the field.
std::vector<PolypCandidate> readCandidates(const std::string& path);
PolypCandidate candidateFromJson(const nlohmann::json& j, const std::string& where);
nlohmann::json candidateToJson(const PolypCandidate& c);

/// Reads findings.json (schema flyover.findings/1). @throw InputError "PATH: ..." when it is not
/// one (wrong schema, a bad field, duplicate ids).
std::vector<Finding> readFindings(const std::string& path);
Finding findingFromJson(const nlohmann::json& j, const std::string& where);
nlohmann::json findingToJson(const Finding& f);
nlohmann::json findingsFileJson(const std::vector<Finding>& findings);
/// Writes findings.json atomically (temporary file + rename).
void writeFindings(const std::string& path, const std::vector<Finding>& findings);

} // namespace flyover
