/// @file progress.h
/// @brief The one small interface through which long-running stage functions report
///        progress and are cancelled (polled coarsely, like OpenVDB's interrupters).
#pragma once

#include <stdexcept>
#include <string>

namespace flyover {

/// Thrown by stage code when Progress::cancelled() became true.
struct Cancelled : std::runtime_error {
    Cancelled() : std::runtime_error("cancelled") {}
};

class Progress {
public:
    virtual ~Progress() = default;
    /// @param fraction  0..1 of the current stage's work
    /// @param what      short description of the current step
    virtual void update(double fraction, const std::string& what) = 0;
    virtual bool cancelled() const { return false; }
};

/// Null-safe helpers for stage code.
inline void reportProgress(Progress* p, double fraction, const std::string& what)
{
    if (p) {
        if (p->cancelled()) throw Cancelled();
        p->update(fraction, what);
    }
}

} // namespace flyover
