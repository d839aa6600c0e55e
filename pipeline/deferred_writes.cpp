#include "pipeline/deferred_writes.h"

#include "pipeline/atomic_write.h"
#include "pipeline/crash_point.h"

#include <filesystem>
#include <system_error>

namespace fs = std::filesystem;

namespace flyover {

namespace {

thread_local DeferredWrites* tDeferred = nullptr;

} // namespace

DeferredWrites::Scope::Scope(DeferredWrites* writes) : mPrevious(tDeferred) { tDeferred = writes; }
DeferredWrites::Scope::~Scope() { tDeferred = mPrevious; }

DeferredWrites* DeferredWrites::active() { return tDeferred; }

DeferredWrites::~DeferredWrites()
{
    std::error_code ec;
    for (const auto& [tmp, target] : mFiles) fs::remove(tmp, ec);
}

void DeferredWrites::add(const std::string& tmpPath, const std::string& path) { mFiles.emplace_back(tmpPath, path); }

std::string DeferredWrites::pendingFile(const std::string& path) const
{
    for (auto it = mFiles.rbegin(); it != mFiles.rend(); ++it)
        if (it->second == path) return it->first;
    return {};
}

void DeferredWrites::rename()
{
    for (const auto& [tmp, target] : mFiles) {
        crashPoint("atomic-write:before-rename");
        fs::rename(tmp, target);
        mRenamed.push_back(target);
    }
    mFiles.clear();
}

void DeferredWrites::sync()
{
    for (const auto& target : mRenamed) fsyncFile(target);
    mRenamed.clear();
}

void DeferredWrites::addReportPart(std::function<void(nlohmann::json&)> complete)
{
    mReportParts.push_back(std::move(complete));
}

void DeferredWrites::completeReport(nlohmann::json& report)
{
    for (const auto& part : mReportParts) part(report);
    mReportParts.clear();
}

std::string writtenFile(const std::string& path)
{
    if (tDeferred) {
        const std::string pending = tDeferred->pendingFile(path);
        if (!pending.empty()) return pending;
    }
    return path;
}

} // namespace flyover
