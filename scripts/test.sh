#!/usr/bin/env bash
# Quick start (b): set up, build in Release, and run the whole test suite with CTest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
BUILD_DIR=${FLYOVER_BUILD_DIR:-build}
ctest --test-dir "$BUILD_DIR" --output-on-failure -j "${FLYOVER_JOBS:-$(nproc)}"
