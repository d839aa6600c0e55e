#include "view/finding_store.h"

#include "volume/error.h"

#include <algorithm>
#include <system_error>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

FindingStore::FindingStore(const std::string& studyDir)
    : mFindingsPath(fs::path(studyDir) / "findings.json"), mCandidatesPath(fs::path(studyDir) / "polyps" / "candidates.json")
{
    if (!fs::exists(mFindingsPath)) return;
    try {
        mFindings = readFindings(mFindingsPath.string());
    } catch (const InputError& e) {
        mFindingsError = e.what();
    }
}

void FindingStore::refreshCandidates()
{
    std::error_code ec;
    const bool exists = fs::is_regular_file(mCandidatesPath, ec);
    const auto time = exists ? fs::last_write_time(mCandidatesPath, ec) : fs::file_time_type{};
    const auto size = exists ? fs::file_size(mCandidatesPath, ec) : 0;
    if (exists == mHaveCandidates && time == mCandidatesTime && size == mCandidatesSize) return;
    mHaveCandidates = exists;
    mCandidatesTime = time;
    mCandidatesSize = size;
    mCandidates.clear();
    mCandidatesError.clear();
    if (!exists) return;
    try {
        mCandidates = readCandidates(mCandidatesPath.string());
    } catch (const InputError& e) {
        mCandidatesError = e.what();
    }
}

void FindingStore::refuseWhenBroken() const
{
    if (!mFindingsError.empty()) throw FindingRefused(409, mFindingsError);
}

json FindingStore::list()
{
    std::lock_guard<std::mutex> lock(mMutex);
    refreshCandidates();
    json candidates = json::array();
    for (const PolypCandidate& c : mCandidates) {
        json j = candidateToJson(c);
        const auto it = std::find_if(mFindings.begin(), mFindings.end(),
                                     [&](const Finding& f) { return f.source == "candidate" && f.candidateId == c.id; });
        j["finding"] = it == mFindings.end() ? json(nullptr) : json(it->id);
        j["status"] = it == mFindings.end() ? json("unreviewed") : json(it->status);
        candidates.push_back(j);
    }
    json findings = json::array();
    for (const Finding& f : mFindings) findings.push_back(findingToJson(f));
    std::string error = mFindingsError;
    if (error.empty()) error = mCandidatesError;
    return json{{"candidates", candidates},
                {"findings", findings},
                {"candidates_file", mHaveCandidates},
                {"error", error}};
}

std::vector<FindingMark> FindingStore::marks()
{
    std::lock_guard<std::mutex> lock(mMutex);
    refreshCandidates();
    std::vector<FindingMark> out;
    for (const PolypCandidate& c : mCandidates) {
        const auto it = std::find_if(mFindings.begin(), mFindings.end(),
                                     [&](const Finding& f) { return f.source == "candidate" && f.candidateId == c.id; });
        if (it == mFindings.end()) out.push_back({c.centroidMm, c.sizeMm, "unreviewed"});
        else if (it->status == "accepted") out.push_back({c.centroidMm, it->sizeMm, "accepted"});
    }
    for (const Finding& f : mFindings)
        if (f.source == "hand" && f.status == "accepted") out.push_back({f.positionMm, f.sizeMm, "hand"});
    return out;
}

std::string FindingStore::nextId() const
{
    unsigned long long next = 1;
    for (const Finding& f : mFindings) {
        if (f.id.size() < 2 || f.id[0] != 'f' || f.id.find_first_not_of("0123456789", 1) != std::string::npos) continue;
        if (f.id.size() < 19) next = std::max(next, std::stoull(f.id.substr(1)) + 1);
    }
    return "f" + std::to_string(next);
}

void FindingStore::save(const std::vector<Finding>& next)
{
    writeFindings(mFindingsPath.string(), next);
    mFindings = next;
}

json FindingStore::review(const std::string& candidateId, const std::string& status, double sizeMm,
                          const std::optional<std::string>& note)
{
    std::lock_guard<std::mutex> lock(mMutex);
    refuseWhenBroken();
    refreshCandidates();
    const auto c = std::find_if(mCandidates.begin(), mCandidates.end(),
                                [&](const PolypCandidate& x) { return x.id == candidateId; });
    if (c == mCandidates.end())
        throw FindingRefused(404, "no candidate with id '" + candidateId.substr(0, 40) + "' in polyps/candidates.json");
    std::vector<Finding> next = mFindings;
    auto f = std::find_if(next.begin(), next.end(),
                          [&](const Finding& x) { return x.source == "candidate" && x.candidateId == candidateId; });
    const bool created = f == next.end();
    if (created) {
        Finding n;
        n.id = nextId();
        n.source = "candidate";
        n.candidateId = c->id;
        n.sizeMm = c->sizeMm;
        n.positionMm = c->centroidMm;
        n.arcMm = c->arcMm;
        n.segment = c->segment;
        n.morphology = c->morphology;
        next.push_back(n);
        f = next.end() - 1;
    }
    f->status = status;
    if (sizeMm >= 0) f->sizeMm = sizeMm;
    if (note) f->note = *note;
    const Finding done = *f;
    save(next);
    return json{{"finding", findingToJson(done)}, {"created", created}};
}

json FindingStore::edit(const std::string& id, double sizeMm, const std::optional<std::string>& status,
                        const std::optional<std::string>& note)
{
    std::lock_guard<std::mutex> lock(mMutex);
    refuseWhenBroken();
    std::vector<Finding> next = mFindings;
    const auto f = std::find_if(next.begin(), next.end(), [&](const Finding& x) { return x.id == id; });
    if (f == next.end()) throw FindingRefused(404, "no finding with id '" + id.substr(0, 40) + "'");
    if (sizeMm >= 0) f->sizeMm = sizeMm;
    if (status) f->status = *status;
    if (note) f->note = *note;
    const Finding done = *f;
    save(next);
    return json{{"finding", findingToJson(done)}, {"created", false}};
}

json FindingStore::addByHand(const Vec3d& positionMm, double arcMm, const std::string& segment, double sizeMm,
                             const std::string& morphology, const std::string& note)
{
    std::lock_guard<std::mutex> lock(mMutex);
    refuseWhenBroken();
    Finding n;
    n.id = nextId();
    n.source = "hand";
    n.status = "accepted";
    n.sizeMm = sizeMm;
    n.positionMm = positionMm;
    n.arcMm = arcMm;
    n.segment = isSegmentName(segment) ? segment : "";
    n.morphology = morphology;
    n.note = note;
    std::vector<Finding> next = mFindings;
    next.push_back(n);
    save(next);
    return json{{"finding", findingToJson(n)}, {"created", true}};
}

bool FindingStore::remove(const std::string& id)
{
    std::lock_guard<std::mutex> lock(mMutex);
    refuseWhenBroken();
    std::vector<Finding> next;
    for (const Finding& f : mFindings)
        if (f.id != id) next.push_back(f);
    if (next.size() == mFindings.size()) return false;
    save(next);
    return true;
}

} // namespace flyover
