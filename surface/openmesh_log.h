/// @file openmesh_log.h
/// @brief Mutes OpenMesh's process-wide log streams (omlog, omout, omerr) for a scope, so
///        its readers, writers and mesh operations do not chatter on the console.
/// @note The streams are global: another thread logging through OpenMesh at the same time
///       loses its messages while a guard is alive (the only consequence).
#pragma once

#include <OpenMesh/Core/System/omstream.hh>

namespace flyover {

class ScopedOpenMeshMute {
public:
    enum Stream : unsigned { LOG = 1u, OUT = 2u, ERR = 4u, ALL = 7u };

    explicit ScopedOpenMeshMute(unsigned streams = ALL)
        : mLog(streams & LOG, ::omlog()), mOut(streams & OUT, ::omout()),
          mErr(streams & ERR, ::omerr())
    {
    }
    ScopedOpenMeshMute(const ScopedOpenMeshMute&) = delete;
    ScopedOpenMeshMute& operator=(const ScopedOpenMeshMute&) = delete;

private:
    /// Disables one stream if asked and restores its previous state on destruction.
    class Muted {
    public:
        Muted(bool mute, OpenMesh::mostream& stream) : mStream(stream), mRestore(mute && stream.is_enabled())
        {
            if (mRestore) mStream.disable();
        }
        ~Muted()
        {
            if (mRestore) mStream.enable();
        }
        Muted(const Muted&) = delete;
        Muted& operator=(const Muted&) = delete;

    private:
        OpenMesh::mostream& mStream;
        bool mRestore;
    };
    Muted mLog, mOut, mErr;
};

} // namespace flyover
