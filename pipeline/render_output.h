/// @file render_output.h
/// @brief What the render steps of `flyover run` and `flyover inspect` share to write their
///        outputs, gathered: staged folders, the cameras' JSON, the PATH lookup, the YUV
///        conversion and the ffmpeg encoder (include the one a file needs).
#pragma once

#include "pipeline/camera_json.h"
#include "pipeline/ffmpeg_video.h"
#include "pipeline/find_on_path.h"
#include "pipeline/staged_folder.h"
#include "pipeline/yuv420.h"
