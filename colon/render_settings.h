/// @file render_settings.h
/// @brief The fly-over cameras' settings and the frame images' options as the render
///        parameters give them: one place for the render steps and for `flyover view`, so that
///        the same pose gives the same pixels in both.
#pragma once

#include "colon/params.h"
#include "render/camera.h"
#include "render/render_view.h"

namespace flyover {

inline FlyoverParams flyoverParamsOf(const RenderParams& rp)
{
    FlyoverParams fp;
    fp.fovDeg = rp.fovDeg;
    fp.rollDeg = rp.rollDeg;
    fp.leftToRight = rp.direction == "right";
    fp.clipOffsetFraction = rp.clipOffsetFraction;
    fp.clipOffsetMm = rp.clipOffsetMm;
    return fp;
}

inline RenderOptions frameOptionsOf(const RenderParams& rp)
{
    RenderOptions ro;
    ro.widthPx = rp.widthPx;
    ro.heightPx = rp.heightPx;
    ro.ost = rp.ost;
    ro.supersample = rp.supersample;
    ro.smoothShading = rp.smoothShading;
    ro.depthCue = rp.depthCue;
    ro.depthCueRangeMm = rp.depthCueMm;
    return ro;
}

} // namespace flyover
