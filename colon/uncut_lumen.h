/// @file uncut_lumen.h
/// @brief The lumen level set as segmentation left it, before the contact cut, and what the
///        graph's early nodes make of it beside the cut (stage_early.cpp): the cut runs mostly
///        on one thread, and the mesh and the centerline need its answer only when it cuts. The
///        mesh and centerline stages take these results when the cut removed no voxel (the
///        level set's values and topology are then theirs: contacts only add metadata); when it
///        cut, the segment stage marks them superseded, the early nodes stop at their next
///        progress report and the stages work on the cut level set. The results are the same
///        either way.
#pragma once

#include "colon/centerline.h"
#include "surface/lumen_surface.h"
#include "volume/centerline_types.h"

#include <openvdb/openvdb.h>

#include <atomic>
#include <optional>

namespace flyover {

struct UncutLumen {
    /// `copy`: a deep copy of the segmentation's level set, which nobody changes, read by
    /// `readers` early nodes.
    UncutLumen(openvdb::FloatGrid::ConstPtr copy, int readers) : mSdf(std::move(copy)), mReaders(readers) {}
    /// The copy, for an early node until it calls doneReading().
    const openvdb::FloatGrid& sdf() const { return *mSdf; }
    /// Called once by each early node when it no longer reads sdf(): the last one frees it.
    void doneReading()
    {
        if (mReaders.fetch_sub(1, std::memory_order_acq_rel) == 1) mSdf.reset();
    }
    /// Set by the segment stage when the contact cut removed voxels: nothing below is of use.
    std::atomic<bool> superseded{false};
    /// Whether the cut removed nothing (settled once the segment stage has ended).
    bool isFinal() const { return !superseded.load(); }

    /// The early mesh node's result (null: none made), its final checks left to the mesh stage.
    std::optional<TriMesh> mesh;
    LumenSurfaceReport meshReport;
    /// The early centerline node's result, traced with centerlineParamsFor(*sdf, ...).
    std::optional<Centerline> centerline;
    CenterlineReport centerlineReport;
    bool centerlineFromTube = false;

    /// Whether `sdf` can be handed on this way: it has no active tiles (the contact cut would
    /// voxelise them, changing the topology that was copied).
    static bool applicable(const openvdb::FloatGrid& sdf) { return !sdf.tree().hasActiveTiles(); }

private:
    openvdb::FloatGrid::ConstPtr mSdf;
    std::atomic<int> mReaders;
};

/// The parameters the centerline stage traces `sdf` with: `given`, with the rectal tube's tip
/// (recorded by segment in the level set's metadata) as the rectum hint unless `given` has one.
/// `fromTube`: whether the hint is the tube's tip.
CenterlineParams centerlineParamsFor(const openvdb::FloatGrid& sdf, const CenterlineParams& given, bool& fromTube);

} // namespace flyover
