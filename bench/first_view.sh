#!/usr/bin/env bash
# Time to the first view in the viewer: a cold `flyover run` of a phantom with
# `flyover view` opened on the same study right after it starts, as a reader would. Measures,
# from the run's start: its first_pair event, the moment /api/status first says ready (the
# study served), the first /api/pair image answered, and the whole run; then the revisions the
# viewer swapped in by the run's end. Median / min / max over RUNS cold runs, each in a fresh
# study in its own folder (FLYOVER_BENCH_DIR, default /tmp/flyover-bench-first-view): never a
# user's study. Needs curl. Usage: bench/first_view.sh [small|medium|full|gca] [RUNS]
# gca: the shared data's real colon mask (gca-colon-00020, run with --mask; no CT, no slices).
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${1:-full}
RUNS=${2:-3}
FLYOVER=${FLYOVER_BIN:-build/bin/flyover}
WORK=${FLYOVER_BENCH_DIR:-/tmp/flyover-bench-first-view}
command -v curl > /dev/null || { echo "first_view.sh: needs curl"; exit 1; }
mkdir -p "$WORK"
if [ "$SIZE" = gca ]; then
  ROOT=$(pwd)
  . bench/shared_data.sh
  INPUT=(--mask "$(shared_data)/real/gca-colon-00020/large_intestine.nii.gz") KIND="real colon mask"
  [ -f "${INPUT[1]}" ] || { echo "no ${INPUT[1]}: the gca mode needs the shared real data"; exit 1; }
else
  CT="$WORK/phantom-$SIZE.nii.gz"
  [ -f "$CT" ] || "$FLYOVER" -q phantom "$CT" --truth "$WORK/phantom-$SIZE.json" --size "$SIZE"
  INPUT=("$CT") KIND=phantom
fi
STUDY="$WORK/study-$SIZE"

. bench/run_log.sh
stats() {  # label values...
  local label=$1 med min max n; shift
  read -r med min max n <<< "$(printf '%s\n' "$@" | median_min_max)"
  printf "%-40s median %8.3f s   min %8.3f   max %8.3f   (%d runs)\n" "$label" "$med" "$min" "$max" "$n"
}

firstPair=() ready=() image=() whole=() revs=()
for _ in $(seq "$RUNS"); do
  rm -rf "$STUDY"
  mkdir -p "$STUDY"
  sync
  t0=$(now)
  "$FLYOVER" run "${INPUT[@]}" --study "$STUDY" --log-json 2> "$WORK/run.jsonl" > /dev/null &
  runPid=$!
  # The run takes the study lock first thing; the viewer then waits for its files.
  for _ in $(seq 200); do [ -s "$STUDY/.flyover/lock" ] && break; sleep 0.01; done
  "$FLYOVER" view --study "$STUDY" > "$WORK/view.out" 2>&1 &
  viewPid=$!
  url=""
  for _ in $(seq 500); do url=$(grep -o 'http://[^ ]*' "$WORK/view.out" || true); [ -n "$url" ] && break; sleep 0.01; done
  [ -n "$url" ] || { echo "flyover view printed no URL:"; cat "$WORK/view.out"; kill $runPid $viewPid; exit 1; }
  base=${url%%/?token=*} token=${url##*token=}
  tReady="" tImage=""
  while kill -0 $runPid 2> /dev/null || [ -z "$tImage" ]; do
    if [ -z "$tReady" ]; then
      curl -sf -H "X-Flyover-Token: $token" "$base/api/status" | grep -q '"ready":true' && tReady=$(now)
    elif [ -z "$tImage" ]; then
      code=$(curl -s -o /dev/null -w '%{http_code}' -H "X-Flyover-Token: $token" "$base/api/pair?arc_mm=0")
      [ "$code" = 200 ] && tImage=$(now)
    fi
    kill -0 $runPid 2> /dev/null || [ -n "$tReady" ] || { echo "the run ended before the viewer was ready"; break; }
    sleep 0.05
  done
  wait $runPid || { echo "flyover run failed:"; tail -3 "$WORK/run.jsonl"; kill $viewPid; exit 1; }
  t1=$(now)
  sleep 1.5  # the viewer's last reload (the final manifest)
  rev=$(curl -sf -H "X-Flyover-Token: $token" "$base/api/status" | sed -n 's/.*"revision":\([0-9]*\).*/\1/p')
  kill $viewPid; wait $viewPid 2> /dev/null || true
  fp=$(sed -n 's/.*"event":"first_pair".*"seconds_since_start":\([0-9.eE+-]*\).*/\1/p' "$WORK/run.jsonl" | head -1)
  firstPair+=("$fp") ready+=("$(secs "$t0" "$tReady")") image+=("$(secs "$t0" "$tImage")")
  whole+=("$(secs "$t0" "$t1")") revs+=("$rev")
done
echo "flyover run + flyover view, $SIZE $KIND, cold (fresh study each run)"
stats "run: first_pair event" "${firstPair[@]}"
stats "viewer: study served (/api/status ready)" "${ready[@]}"
stats "viewer: first /api/pair image" "${image[@]}"
stats "whole run (viewer open)" "${whole[@]}"
echo "revisions swapped in by the end of the run: ${revs[*]}"
