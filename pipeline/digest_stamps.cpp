#include "pipeline/digest_stamps.h"

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "volume/error.h"

#include <nlohmann/json.hpp>

#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <vector>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

std::string absolutePath(const std::string& path)
{
    std::error_code ec;
    const fs::path a = fs::absolute(path, ec);
    return ec ? path : a.lexically_normal().string();
}

} // namespace

DigestStamps::DigestStamps(std::string stampsFile) : mFile(std::move(stampsFile))
{
    std::error_code ec;
    if (!fs::exists(mFile, ec)) return;
    try {
        const json j = readJson(mFile);
        if (j.value("schema", "") != "flyover.stamps/1" || !j.contains("files") || !j["files"].is_object()) return;
        for (auto it = j["files"].begin(); it != j["files"].end(); ++it) {
            const json& e = it.value();
            Stamp s;
            s.dev = e.at("dev").get<unsigned long long>();
            s.ino = e.at("ino").get<unsigned long long>();
            s.size = e.at("size").get<unsigned long long>();
            s.mtimeNs = e.at("mtime_ns").get<long long>();
            s.ctimeNs = e.at("ctime_ns").get<long long>();
            s.digest = e.at("digest").get<std::string>();
            mStamps[it.key()] = s;
        }
        mLoadedAny = !mStamps.empty();
    } catch (const std::exception&) {
        mStamps.clear();  // damaged: hash everything
    }
}

bool DigestStamps::identity(const std::string& path, Stamp& out)
{
    struct stat st{};
    if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
    out.dev = static_cast<unsigned long long>(st.st_dev);
    out.ino = static_cast<unsigned long long>(st.st_ino);
    out.size = static_cast<unsigned long long>(st.st_size);
    out.mtimeNs = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
    out.ctimeNs = static_cast<long long>(st.st_ctim.tv_sec) * 1000000000LL + st.st_ctim.tv_nsec;
    return true;
}

std::string DigestStamps::fileDigest(const std::string& path)
{
    const std::string key = absolutePath(path);
    Stamp now;
    if (identity(key, now)) {
        std::lock_guard<std::mutex> lock(mMutex);
        const auto it = mStamps.find(key);
        if (it != mStamps.end() && it->second == now) return it->second.digest;
    }
    const std::string d = flyover::fileDigest(path);
    std::lock_guard<std::mutex> lock(mMutex);
    mHashed[key] = d;
    return d;
}

std::string DigestStamps::digest(const std::string& path)
{
    // artifactDigest's digest, each file's digest from its stamp where it still holds.
    return artifactDigest(path, [this](const std::string& f) { return fileDigest(f); });
}

void DigestStamps::hashed(const std::string& path, const std::string& digest)
{
    std::lock_guard<std::mutex> lock(mMutex);
    mHashed[absolutePath(path)] = digest;
}

void DigestStamps::save()
{
    std::lock_guard<std::mutex> lock(mMutex);
    bool changed = false;
    for (const auto& [path, d] : mHashed) {
        Stamp s;
        if (!identity(path, s)) continue;
        s.digest = d;
        const auto it = mStamps.find(path);
        if (it != mStamps.end() && it->second == s && it->second.digest == d) continue;
        mStamps[path] = s;
        changed = true;
    }
    mHashed.clear();
    for (auto it = mStamps.begin(); it != mStamps.end();) {
        Stamp s;
        if (identity(it->first, s)) {
            ++it;
        } else {
            it = mStamps.erase(it);
            changed = true;
        }
    }
    if (!changed) return;
    json files = json::object();
    for (const auto& [path, s] : mStamps)
        files[path] = json{{"dev", s.dev},         {"ino", s.ino},           {"size", s.size},
                           {"mtime_ns", s.mtimeNs}, {"ctime_ns", s.ctimeNs}, {"digest", s.digest}};
    writeJson(mFile, json{{"schema", "flyover.stamps/1"}, {"files", files}});
}

} // namespace flyover
