#include "pipeline/artifact_store.h"

#include "pipeline/artifact_io.h"
#include "pipeline/digest_stamps.h"
#include "volume/error.h"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <sys/file.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

// ---------------------------------------------------------------------------------- lock

StudyLock::StudyLock(const std::string& studyDir, bool wait)
{
    const fs::path dir = fs::path(studyDir) / ".flyover";
    std::error_code ec;
    fs::create_directories(dir, ec);
    const std::string path = (dir / "lock").string();
    mFd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (mFd < 0) throw InputError(path + ": cannot open the study lock: " + std::strerror(errno));
    if (::flock(mFd, LOCK_EX | (wait ? 0 : LOCK_NB)) != 0) {
        std::string holder;
        char buf[32] = {};
        if (::pread(mFd, buf, sizeof buf - 1, 0) > 0) holder = std::string(" (pid ") + buf + ")";
        while (!holder.empty() && (holder.back() == '\n')) holder.pop_back();
        ::close(mFd);
        mFd = -1;
        throw StudyBusy(studyDir + ": another flyover run is writing this study" + holder +
                        "; wait for it to finish or pass --wait");
    }
    const std::string pid = std::to_string(::getpid());
    if (::ftruncate(mFd, 0) == 0) {
        [[maybe_unused]] auto n = ::pwrite(mFd, pid.data(), pid.size(), 0);
    }
}

StudyLock::~StudyLock()
{
    if (mFd >= 0) {
        ::flock(mFd, LOCK_UN);
        ::close(mFd);
    }
}

// ---------------------------------------------------------------------------------- keys

std::string stageKey(const std::string& stage, int version, const json& params,
                     const std::map<std::string, std::string>& inputDigests)
{
    // nlohmann::json objects keep keys sorted, so dump() is canonical.
    const json key{{"stage", stage}, {"version", version}, {"parameters", params}, {"inputs", inputDigests}};
    return stringDigest(key.dump());
}

std::string artifactDigest(const std::string& path,
                           const std::function<std::string(const std::string&)>& fileDigestOf)
{
    const auto digestOf = [&](const std::string& f) { return fileDigestOf ? fileDigestOf(f) : fileDigest(f); };
    if (!fs::is_directory(path)) return digestOf(path);
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(path))
        if (e.is_regular_file()) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    std::string listing;
    for (const auto& f : files) listing += f.filename().string() + ":" + digestOf(f.string()) + "\n";
    return stringDigest(listing);
}

// ---------------------------------------------------------------------------------- store

namespace {

std::string extensionOf(const std::string& name)
{
    const auto dot = name.rfind('.');
    return dot == std::string::npos ? ".d" : name.substr(dot);
}

/// Replaces `target` by a hard link to `source` (a file) or by a folder of hard links to
/// `source`'s files, atomically from the point of view of readers.
void linkInto(const fs::path& source, const fs::path& target)
{
    const fs::path tmp = target.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string());
    fs::remove_all(tmp);
    if (fs::is_directory(source)) {
        fs::create_directories(tmp);
        for (const auto& e : fs::directory_iterator(source))
            fs::create_hard_link(e.path(), tmp / e.path().filename());
        const fs::path old = target.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-old-" + target.filename().string());
        fs::remove_all(old);
        if (fs::exists(target)) fs::rename(target, old);
        fs::rename(tmp, target);
        fs::remove_all(old);
    } else {
        fs::create_hard_link(source, tmp);
        fs::rename(tmp, target);
    }
}

bool sameFile(const fs::path& a, const fs::path& b)
{
    std::error_code ec;
    return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec);
}

uint64_t bytesOf(const fs::path& p)
{
    std::error_code ec;
    if (!fs::is_directory(p, ec)) return fs::file_size(p, ec);
    uint64_t n = 0;
    for (const auto& e : fs::directory_iterator(p, ec)) n += fs::file_size(e.path(), ec);
    return n;
}

} // namespace

ArtifactStore::ArtifactStore(const std::string& studyDir, DigestStamps* stamps) : mDir(studyDir), mStamps(stamps)
{
    fs::create_directories(fs::path(mDir) / ".flyover" / "objects");
    fs::create_directories(fs::path(mDir) / ".flyover" / "records");
}

std::string ArtifactStore::recordFileName(const std::string& stage, const std::string& key)
{
    return stage + "-" + key + ".json";
}

std::string ArtifactStore::objectPath(const std::string& name, const std::string& digest) const
{
    return (fs::path(mDir) / ".flyover" / "objects" / (digest + extensionOf(name))).string();
}

void ArtifactStore::removeStaleTemporaries() const
{
    for (const fs::path& d : {fs::path(mDir), fs::path(mDir) / ".flyover", fs::path(mDir) / ".flyover" / "objects",
                              fs::path(mDir) / ".flyover" / "records"}) {
        std::error_code ec;
        for (const auto& e : fs::directory_iterator(d, ec))
            if (e.path().filename().string().rfind(".tmp-", 0) == 0) fs::remove_all(e.path(), ec);
    }
}

std::optional<json> ArtifactStore::findRecord(const std::string& stage, const std::string& key) const
{
    const fs::path p = fs::path(mDir) / ".flyover" / "records" / recordFileName(stage, key);
    if (!fs::exists(p)) return std::nullopt;
    try {
        json r = readJson(p.string());
        if (r.value("key", "") != key || !r.contains("outputs")) return std::nullopt;
        return r;
    } catch (const InputError&) {
        return std::nullopt;  // a damaged record is a cache miss
    }
}

std::string ArtifactStore::verifyRecord(const json& record) const
{
    for (auto it = record.at("outputs").begin(); it != record.at("outputs").end(); ++it) {
        const std::string obj = objectPath(it.key(), it.value().get<std::string>());
        std::error_code ec;
        if (!fs::exists(obj, ec)) return it.key() + " is missing from the cache";
        std::string digest;
        try {
            digest = mStamps ? mStamps->digest(obj) : artifactDigest(obj);
        } catch (const InputError&) {
            return it.key() + " is unreadable";
        }
        if (digest != it.value().get<std::string>()) return it.key() + " is corrupt (digest mismatch)";
    }
    return {};
}

void ArtifactStore::materialize(const json& record) const
{
    for (auto it = record.at("outputs").begin(); it != record.at("outputs").end(); ++it) {
        const fs::path obj = objectPath(it.key(), it.value().get<std::string>());
        const fs::path target = fs::path(mDir) / it.key();
        if (fs::is_directory(obj)) {
            // A folder is current when it holds exactly the object's files.
            bool current = fs::is_directory(target);
            if (current) {
                std::size_t n = 0;
                for (const auto& e : fs::directory_iterator(target)) {
                    ++n;
                    current = current && sameFile(e.path(), obj / e.path().filename());
                }
                for ([[maybe_unused]] const auto& e : fs::directory_iterator(obj)) --n;
                current = current && n == 0;
            }
            if (!current) linkInto(obj, target);
        } else if (!sameFile(obj, target)) {
            linkInto(obj, target);
        }
    }
}

void ArtifactStore::commit(const json& record) const
{
    for (auto it = record.at("outputs").begin(); it != record.at("outputs").end(); ++it) {
        const fs::path obj = objectPath(it.key(), it.value().get<std::string>());
        const fs::path produced = fs::path(mDir) / it.key();
        if (fs::exists(obj)) {
            // Same content already stored (e.g. a parameter that did not change this output):
            // point the study at the stored object so that they share storage, unless the
            // stored copy was damaged since, in which case the fresh one replaces it.
            std::string stored;
            try {
                stored = artifactDigest(obj.string());
            } catch (const InputError&) {
            }
            if (stored == it.value().get<std::string>()) {
                if (!sameFile(obj, produced)) linkInto(obj, produced);
                continue;
            }
        }
        linkInto(produced, obj);
    }
    crashPoint("store:objects-linked");
    const std::string stage = record.at("stage").get<std::string>();
    const std::string key = record.at("key").get<std::string>();
    writeJson((fs::path(mDir) / ".flyover" / "records" / recordFileName(stage, key)).string(), record);
}

void ArtifactStore::touch(const std::string& stage, const std::string& key) const
{
    std::error_code ec;
    fs::last_write_time(fs::path(mDir) / ".flyover" / "records" / recordFileName(stage, key),
                        fs::file_time_type::clock::now(), ec);
}

bool ArtifactStore::anotherRecordHas(const std::string& stage, const std::string& name, const std::string& digest,
                                     const std::string& exceptKey) const
{
    std::error_code ec;
    const std::string prefix = stage + "-";
    for (const auto& e : fs::directory_iterator(fs::path(mDir) / ".flyover" / "records", ec)) {
        const std::string file = e.path().filename().string();
        if (file.rfind(prefix, 0) != 0 || e.path().extension() != ".json" ||
            file == recordFileName(stage, exceptKey))
            continue;
        try {
            const json r = readJson(e.path().string());
            if (r.value("stage", "") == stage && r.contains("outputs") && r["outputs"].value(name, "") == digest)
                return true;
        } catch (const std::exception&) {
            // a damaged record proves nothing
        }
    }
    return false;
}

void ArtifactStore::dropRecord(const std::string& stage, const std::string& key) const
{
    std::error_code ec;
    fs::remove(fs::path(mDir) / ".flyover" / "records" / recordFileName(stage, key), ec);
}

uint64_t ArtifactStore::objectBytes() const
{
    uint64_t n = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(fs::path(mDir) / ".flyover" / "objects", ec)) n += bytesOf(e.path());
    return n;
}

uint64_t ArtifactStore::evict(uint64_t maxBytes, const std::set<std::string>& keep) const
{
    const fs::path records = fs::path(mDir) / ".flyover" / "records";
    const fs::path objects = fs::path(mDir) / ".flyover" / "objects";
    uint64_t total = objectBytes();
    if (total <= maxBytes) return 0;

    struct Rec { fs::path path; fs::file_time_type used; json body; };
    std::vector<Rec> recs;
    for (const auto& e : fs::directory_iterator(records)) {
        if (e.path().extension() != ".json") continue;
        try {
            recs.push_back({e.path(), fs::last_write_time(e.path()), readJson(e.path().string())});
        } catch (const InputError&) {
            fs::remove(e.path());
        }
    }
    std::sort(recs.begin(), recs.end(), [](const Rec& a, const Rec& b) { return a.used < b.used; });

    auto referenced = [&](const std::vector<Rec>& live) {
        std::set<std::string> names;
        for (const auto& r : live)
            for (auto it = r.body["outputs"].begin(); it != r.body["outputs"].end(); ++it)
                names.insert(fs::path(objectPath(it.key(), it.value().get<std::string>())).filename().string());
        return names;
    };
    const uint64_t before = total;
    std::vector<Rec> live = recs;
    for (const auto& r : recs) {
        if (total <= maxBytes) break;
        if (keep.count(r.path.filename().string())) continue;
        fs::remove(r.path);
        live.erase(std::find_if(live.begin(), live.end(), [&](const Rec& x) { return x.path == r.path; }));
        const auto names = referenced(live);
        for (const auto& e : fs::directory_iterator(objects))
            if (!names.count(e.path().filename().string())) fs::remove_all(e.path());
        total = objectBytes();
    }
    return before - total;
}

} // namespace flyover
