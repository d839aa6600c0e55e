#!/usr/bin/env bash
# Re-run of an unchanged study: wall time of `flyover run` when every stage is reused.
# Usage: bench/rerun.sh [small|medium|full] [runs]   (build first: scripts/build.sh)
# Prints the first (computing) run's time and the median / min / max of the re-runs.
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${1:-full}
RUNS=${2:-9}
FLYOVER=${FLYOVER_BIN:-build/bin/flyover}
WORK=${FLYOVER_BENCH_DIR:-/tmp/flyover-bench-rerun}
mkdir -p "$WORK"
CT="$WORK/phantom-$SIZE.nii.gz"
[ -f "$CT" ] || "$FLYOVER" -q phantom "$CT" --truth "$WORK/phantom-$SIZE.json" --size "$SIZE"
rm -rf "$WORK/study-$SIZE"
. bench/run_log.sh
t0=$(now); "$FLYOVER" -q run "$CT" --study "$WORK/study-$SIZE"; t1=$(now)
echo "first run (all stages computed), $SIZE phantom: $(secs "$t0" "$t1") s"
times=()
for _ in $(seq "$RUNS"); do
  t0=$(now); "$FLYOVER" -q run "$CT" --study "$WORK/study-$SIZE"; t1=$(now)
  times+=("$(secs "$t0" "$t1")")
done
read -r med min max n <<< "$(printf '%s\n' "${times[@]}" | median_min_max)"
printf "unchanged re-run, %s phantom, %d runs: median %.3f s, min %.3f s, max %.3f s\n" "$SIZE" "$n" "$med" "$min" "$max"
