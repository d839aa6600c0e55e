/// @file stage_context.h
/// @brief What a stage body sees of a run (internal to pipeline/): the options, the study
///        folder, and the objects earlier stages of the same run left in memory. Each stage
///        body lives in its own stage_<name>.cpp and returns its report for the manifest.
#pragma once

#include "pipeline/study.h"
#include "surface/mesh_types.h"
#include "volume/centerline_types.h"
#include "volume/progress.h"
#include "volume/vec3.h"

#include <nlohmann/json.hpp>
#include <openvdb/openvdb.h>

#include <filesystem>
#include <mutex>
#include <optional>
#include <string>

namespace flyover {

/// Objects handed from stage to stage in memory within one run.
struct StudyState {
    openvdb::FloatGrid::Ptr hu;
    openvdb::FloatGrid::Ptr sdf;
    std::optional<Centerline> centerline;
    std::optional<TriMesh> mesh;
};

class StudyRun {
public:
    explicit StudyRun(const RunOptions& o) : opt(o), dir(o.studyDir) {}

    std::string path(const std::string& name) const { return (dir / name).string(); }

    /// The lumen level set: from memory when segment ran in this run, else from lumen.vdb.
    /// Thread-safe (centerline and mesh ask for it at the same time).
    openvdb::FloatGrid::Ptr sdf();

    const RunOptions& opt;
    std::filesystem::path dir;
    StudyState state;

private:
    std::mutex mLoadMutex;
};

inline nlohmann::json vec3Json(const Vec3d& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

// Stage bodies: each writes its artifacts (atomically) and returns its report.
nlohmann::json runIngest(StudyRun& run, Progress* progress);
nlohmann::json runSegment(StudyRun& run, Progress* progress);
/// The segment stage when the study starts from an external mask (`flyover run --mask FILE
/// [--label N]`, with or without a CT): the lumen is the mask's label, matched to the CT's grid
/// when there is a CT (ct.vdb from ingest), else on the mask's own geometry. The report records
/// the mask's geometry, which `flyover export --lumen` uses when the study has no CT.
nlohmann::json runSegmentFromMask(StudyRun& run, const std::string& maskPath, Progress* progress);
nlohmann::json runCenterline(StudyRun& run, Progress* progress);
struct LumenSegmentation;
/// Finds and cuts the contacts between touching loops in seg's mask and sdf (volume/contacts.h),
/// records them in the sdf's metadata (read by the centerline stage), logs them, returns the
/// report.
nlohmann::json cutLumenContacts(StudyRun& run, LumenSegmentation& seg);
/// The contacts recorded in the lumen level set's metadata by cutLumenContacts, with the arcs
/// of `centerline` nearest to their two sides; null when there are none recorded.
nlohmann::json contactsAlongPath(const openvdb::FloatGrid& sdf, const Centerline& centerline);
nlohmann::json runMesh(StudyRun& run, Progress* progress);
nlohmann::json runRender(StudyRun& run, Progress* progress);

} // namespace flyover
