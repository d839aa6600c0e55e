#include "view/bookmarks.h"

#include "pipeline/artifact_io.h"
#include "volume/error.h"
#include "volume/image.h"

#include <chrono>
#include <ctime>
#include <filesystem>
#include <fstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

std::string utcNow()
{
    const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&now, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

} // namespace

BookmarkStore::BookmarkStore(std::string path) : mPath(std::move(path))
{
    if (!fs::exists(mPath)) return;
    const json j = readJson(mPath);
    if (!j.is_object() || !j.contains("bookmarks") || !j["bookmarks"].is_array())
        throw InputError(mPath + ": not a bookmarks file (no \"bookmarks\" list); move it away to start afresh");
    for (const auto& b : j["bookmarks"]) {
        if (!b.is_object() || !b.contains("id") || !b["id"].is_string())
            throw InputError(mPath + ": a bookmark without a string \"id\"");
        mItems.push_back(b);
        const std::string id = b["id"].get<std::string>();
        if (id.rfind("b", 0) == 0) {
            try {
                mNextId = std::max(mNextId, std::stoull(id.substr(1)) + 1);
            } catch (const std::exception&) {
                // a foreign id: kept as it is
            }
        }
    }
}

json BookmarkStore::list() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    return mItems;
}

json BookmarkStore::add(const json& fields)
{
    std::lock_guard<std::mutex> lock(mMutex);
    json b = fields;
    b["id"] = "b" + std::to_string(mNextId);
    b["created"] = utcNow();
    json saved = mItems;
    mItems.push_back(b);
    try {
        save();
    } catch (...) {
        mItems = saved;
        throw;
    }
    ++mNextId;
    return b;
}

bool BookmarkStore::remove(const std::string& id)
{
    std::lock_guard<std::mutex> lock(mMutex);
    json kept = json::array();
    for (const auto& b : mItems)
        if (b.value("id", "") != id) kept.push_back(b);
    if (kept.size() == mItems.size()) return false;
    std::swap(kept, mItems);
    try {
        save();
    } catch (...) {
        std::swap(kept, mItems);
        throw;
    }
    return true;
}

void BookmarkStore::save() const
{
    writeJson(mPath, json{{"schema", "flyover.bookmarks/1"}, {"world_frame", WORLD_FRAME}, {"bookmarks", mItems}});
}

} // namespace flyover
