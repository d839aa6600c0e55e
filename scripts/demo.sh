#!/usr/bin/env bash
# Quick start (a): set up, build in Release, and run the demo on the built-in phantom.
set -euo pipefail
cd "$(dirname "$0")/.."
# The demo runs only the program: its tests and benchmarks are left unbuilt.
FLYOVER_TARGETS=flyover bash scripts/build.sh
BUILD_DIR=${FLYOVER_BUILD_DIR:-build}
OUT=${FLYOVER_DEMO_DIR:-demo}
mkdir -p "$OUT"
"$BUILD_DIR/bin/flyover" phantom "$OUT/phantom_ct.nii.gz" --truth "$OUT/phantom_truth.json" \
    --truth-mask "$OUT/phantom_lumen.nii.gz" --size small --seed 1
"$BUILD_DIR/bin/flyover" run "$OUT/phantom_ct.nii.gz" --study "$OUT/study"
echo
echo "Demo images:"
echo "  overview (OST of the whole colon, anterior view): $(realpath "$OUT/study/overview.png")"
echo "  fly-over frame pairs (camera 0 | camera 1):       $(realpath "$OUT/study/frames")/pair_*.png"
echo "  camera poses of every frame:                      $(realpath "$OUT/study/frames/poses.json")"
echo "  all artifacts and manifest.json:                  $(realpath "$OUT/study")"
echo
echo "Fly over it interactively (a local web page; open the URL it prints, Ctrl-C stops it):"
echo "  $BUILD_DIR/bin/flyover view --study $(realpath "$OUT/study")"
