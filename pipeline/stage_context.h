// The colon's run context moved to colon/study_run.h; this forwarding header stays only until the
// colon's render steps and centerline stage (being changed elsewhere) include it by its new name.
#pragma once
#include "colon/study_run.h"
