/// @file speculative_mesh.h
/// @brief Internal to pipeline/ (issue 15): the lumen surface meshed beside the contact cut.
///        The segment stage's contact search (volume/contacts.h) runs mostly on one thread;
///        the mesh does not need its answer unless it cuts. So the segment stage starts
///        makeLumenSurface() on a deep copy of the lumen level set before the cut, on a thread
///        of its own, and hands it to the mesh stage only when the cut removed no voxel (the
///        level set's values and topology are then those the mesh stage would mesh: contacts
///        only add metadata). When something was cut, the copy's mesh is cancelled and the
///        mesh stage meshes the cut level set as before. The result is the same either way.
#pragma once

#include "surface/lumen_surface.h"

#include <openvdb/openvdb.h>

#include <atomic>
#include <future>

namespace flyover {

class SpeculativeMesh {
public:
    /// Starts meshing a deep copy of `sdf` with `params` on its own thread; the final checks
    /// are left to the taker (makeLumenSurface's deferFinalChecks) when `deferFinalChecks`.
    SpeculativeMesh(const openvdb::FloatGrid& sdf, const MeshParams& params, bool deferFinalChecks = false);
    /// Cancels a mesh still running (at its next progress report) and waits for it.
    ~SpeculativeMesh();
    SpeculativeMesh(const SpeculativeMesh&) = delete;
    SpeculativeMesh& operator=(const SpeculativeMesh&) = delete;

    /// Whether `sdf` can be meshed this way: it has no active tiles (the contact cut would
    /// voxelise them, changing the topology that was copied).
    static bool applicable(const openvdb::FloatGrid& sdf);

    /// Waits for the mesh and returns it, its report in `report`; rethrows what meshing
    /// threw. Call once.
    TriMesh take(LumenSurfaceReport& report);

private:
    std::atomic<bool> mCancel{false};
    std::future<TriMesh> mResult;
    LumenSurfaceReport mReport;
};

} // namespace flyover
