/// @file render_steps.h
/// @brief What the colon's render steps (stage_render.cpp: frames, flythrough, overviews,
///        video; stage_coverage.cpp: coverage and review) share: the options JSON of a
///        rendered image and the loop-local window of a view.
#pragma once

#include "colon/study_run.h"
#include "render/render_view.h"

#include <nlohmann/json.hpp>

#include <cstddef>

namespace flyover {

/// How a frame was rendered, so that any frame can be reproduced from the JSON alone.
nlohmann::json renderOptionsJson(const RenderOptions& ro);

/// `ro` for a fly-over or review view standing at centerline index `index`: loop-local when
/// the run has owners (render.loop_reach_mm > 0).
RenderOptions loopLocal(RenderOptions ro, const RenderInputs& in, const RenderParams& rp, std::size_t index,
                        double clStep);

/// What loop-local OST did: the reach and how the owners were found (artifacts hold no
/// timings: the same inputs give the same files); `withSeconds` adds the time, for a report.
nlohmann::json loopJson(const RenderInputs& in, const RenderParams& rp, bool withSeconds = false);

} // namespace flyover
