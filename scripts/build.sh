#!/usr/bin/env bash
# Installs the Debian packages (scripts/setup.sh) and builds flyover in Release into build/:
# everything, or only the targets named in FLYOVER_TARGETS (space-separated).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BUILD_DIR=${FLYOVER_BUILD_DIR:-build}
JOBS=${FLYOVER_JOBS:-$(nproc)}
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
# shellcheck disable=SC2086
cmake --build "$BUILD_DIR" -j "$JOBS" ${FLYOVER_TARGETS:+--target $FLYOVER_TARGETS}
