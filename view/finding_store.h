/// @file finding_store.h
/// @brief The viewer's findings: the polyps stage's candidates (polyps/candidates.json, read
///        again whenever the file changes) and the reader's findings.json (flyover.findings/1),
///        rewritten atomically under a mutex on every change, as bookmarks are. A findings.json
///        that cannot be read is never overwritten: the store reports it and refuses changes.
#pragma once

#include "colon/findings.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

namespace flyover {

/// What the store refuses: the message names the field or the file (the route says 4xx).
struct FindingRefused : std::runtime_error {
    FindingRefused(int s, const std::string& m) : std::runtime_error(m), status(s) {}
    int status;
};

/// A candidate or finding to mark on an image: where, how big, and what the reader made of it.
struct FindingMark {
    Vec3d positionMm;
    double sizeMm = 0;
    std::string kind;  ///< "unreviewed" or "accepted" (a candidate), "hand" (a finding by hand)
};

class FindingStore {
public:
    explicit FindingStore(const std::string& studyDir);

    /// {"candidates": [candidate + "finding" (id or null), "status"], "findings": [...],
    ///  "candidates_file": bool, "error": "" or why findings.json or candidates.json is unusable}.
    nlohmann::json list();

    /// What to mark: every candidate not rejected (at its centroid, with the finding's edited
    /// size once accepted) and every accepted finding added by hand.
    std::vector<FindingMark> marks();

    /// Accepts or rejects a candidate (a new finding, or its existing one updated).
    /// `sizeMm` < 0: keep (new: the candidate's). @return {finding, created}.
    nlohmann::json review(const std::string& candidateId, const std::string& status, double sizeMm,
                          const std::optional<std::string>& note);
    /// Edits a finding: size (>= 0), status, note. @throw FindingRefused 404 for an unknown id.
    nlohmann::json edit(const std::string& id, double sizeMm, const std::optional<std::string>& status,
                        const std::optional<std::string>& note);
    /// A finding added by hand at a picked point (arc and segment from the path), accepted.
    nlohmann::json addByHand(const Vec3d& positionMm, double arcMm, const std::string& segment, double sizeMm,
                             const std::string& morphology, const std::string& note);
    /// @return false when no finding has that id.
    bool remove(const std::string& id);

private:
    void refreshCandidates();
    void refuseWhenBroken() const;
    void save(const std::vector<Finding>& next);
    std::string nextId() const;

    std::filesystem::path mFindingsPath, mCandidatesPath;
    std::mutex mMutex;
    std::vector<Finding> mFindings;
    std::string mFindingsError;
    std::vector<PolypCandidate> mCandidates;
    std::string mCandidatesError;
    std::filesystem::file_time_type mCandidatesTime{};
    std::uintmax_t mCandidatesSize = 0;
    bool mHaveCandidates = false;
};

} // namespace flyover
