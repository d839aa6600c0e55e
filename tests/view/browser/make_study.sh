#!/usr/bin/env bash
# CTest fixture of the browser test: a small phantom (seed 1) and its study, made quickly
# (no video, no fly-through pairs, few saved pairs, coarser coverage).
#   make_study.sh FLYOVER_BIN OUT_DIR   ->  OUT_DIR/ct.nii.gz, OUT_DIR/truth.json, OUT_DIR/study/
set -euo pipefail
flyover=$1
out=$2
rm -rf "$out"
mkdir -p "$out"
"$flyover" --quiet phantom "$out/ct.nii.gz" --truth "$out/truth.json" --size small --seed 1
"$flyover" --quiet run "$out/ct.nii.gz" --study "$out/study" \
  --set render.video=false --set render.flythrough_frames=false \
  --set render.frame_step_mm=250 --set render.coverage_step_mm=6
echo "make_study.sh: study ready in $out/study"
