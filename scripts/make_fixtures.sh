#!/usr/bin/env bash
# Regenerates the image fixtures in data/fixtures/ (see data/fixtures/README.md) with ITK's
# own writers. Usage: scripts/make_fixtures.sh [REAL_DATA_DIR]
#   REAL_DATA_DIR: the totalsegmentator-example folder (default: ../shared/data/real/...);
#   without it, data/fixtures/real/ is left as it is.
# Builds scripts/fixtures/ (a standalone CMake project) in $BUILD_DIR (default build-fixtures).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build-fixtures}
REAL=${1:-../shared/data/real/totalsegmentator-example}
cmake -S scripts/fixtures -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$BUILD_DIR" >/dev/null
if [ -d "$REAL" ]; then
  "$BUILD_DIR/make_fixtures" data/fixtures "$REAL" >/dev/null
  # The colon labels on the example_ct_sm grid, unchanged (41 kB together).
  install -m 644 "$REAL/example_seg.nii.gz" "$REAL/example_seg_fast_colon.nii.gz" data/fixtures/real/
else
  echo "make_fixtures.sh: $REAL not found; real/ fixtures left unchanged" >&2
  "$BUILD_DIR/make_fixtures" data/fixtures >/dev/null
fi
echo "make_fixtures.sh: data/fixtures regenerated ($(du -sh data/fixtures | cut -f1))"
