/// @file bookmarks.h
/// @brief The viewer's bookmarks: camera poses with a note, kept in the study's bookmarks.json
///        (schema flyover.bookmarks/1), rewritten atomically (temporary file + rename) under a
///        mutex on every change. `flyover run` never touches the file; `flyover clean` leaves it.
#pragma once

#include <nlohmann/json.hpp>

#include <mutex>
#include <string>

namespace flyover {

class BookmarkStore {
public:
    /// Reads `path` when it exists. @throw InputError naming the file when it is not a valid
    /// bookmarks file (it is then never overwritten by accident).
    explicit BookmarkStore(std::string path);

    /// Every bookmark, oldest first.
    nlohmann::json list() const;
    /// Adds a bookmark: `fields` holds note, arc_mm, roll_deg, direction, mode,
    /// clip_offset_fraction (already validated); returns it with its new id and created time.
    nlohmann::json add(const nlohmann::json& fields);
    /// @return false when no bookmark has that id.
    bool remove(const std::string& id);

private:
    void save() const;

    std::string mPath;
    mutable std::mutex mMutex;
    nlohmann::json mItems = nlohmann::json::array();
    unsigned long long mNextId = 1;
};

} // namespace flyover
