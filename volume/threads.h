// How many threads the caller's work may use at most: the smaller of the current task arena's
// concurrency and TBB's global limit (`--threads`). Work that is only worth splitting when a
// second thread can run (side-by-side searches, speculative stages) asks this.
#pragma once

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>

namespace flyover {

inline int threadsThatMayRun()
{
    return std::min<int>(tbb::this_task_arena::max_concurrency(),
                         static_cast<int>(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
}

} // namespace flyover
