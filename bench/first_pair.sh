#!/usr/bin/env bash
# Time to viewing: cold runs of `flyover run` on a phantom, each in a fresh study.
# Usage: bench/first_pair.sh [small|medium|full|gca] [runs] [extra flyover run arguments...]
# gca: the real colon mask of the shared data (gca-colon-00020, 3.6 L, 2.4 m of colon; no CT,
# so no ingest and no ITK reference), run with --mask: how a real colon's length and shape
# weigh on the path to the first pair, which the phantoms do not show.
# Prints, as the median / min / max over the cold runs: CT -> first fly-over pair (the
# "first_pair" event's seconds_since_start), the whole run, and the peak RSS (GNU time); then
# the median of unchanged re-runs; the process CPU seconds (user + system) at the first pair and
# at the end (steadier than wall times on a shared machine); then the plain ITK reference
# (bench/itk_reference: ITK read + threshold + marching cubes of the same file) and the ratio
# first pair / reference (the target is <= 0.75), and the same against ITK's own mesher
# (itk_reference --mesher itk: ITK alone, one thread for the mesh). Works only in its own folder (FLYOVER_BENCH_DIR, default
# /tmp/flyover-bench-first-pair): never in a user's study. Build first: scripts/build.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${1:-full}
RUNS=${2:-5}
shift $(( $# < 2 ? $# : 2 ))
FLYOVER=${FLYOVER_BIN:-build/bin/flyover}
WORK=${FLYOVER_BENCH_DIR:-/tmp/flyover-bench-first-pair}
mkdir -p "$WORK"
if [ "$SIZE" = gca ]; then
  ROOT=$(pwd)
  . bench/shared_data.sh
  CT="" KIND="real colon mask" FROM=mask
  INPUT=(--mask "$(shared_data)/real/gca-colon-00020/large_intestine.nii.gz")
  [ -f "${INPUT[1]}" ] || { echo "no ${INPUT[1]}: the gca mode needs the shared real data"; exit 1; }
else
  CT="$WORK/phantom-$SIZE.nii.gz"
  [ -f "$CT" ] || "$FLYOVER" -q phantom "$CT" --truth "$WORK/phantom-$SIZE.json" --size "$SIZE"
  INPUT=("$CT") KIND=phantom FROM=CT
fi
STUDY="$WORK/study-$SIZE"
TIME=()
[ -x /usr/bin/time ] && TIME=(/usr/bin/time -f "%M" -o "$WORK/rss")

. bench/run_log.sh
stats() {  # label unit values...
  local label=$1 unit=$2 med min max n; shift 2
  read -r med min max n <<< "$(printf '%s\n' "$@" | median_min_max)"
  printf "%-34s median %9.3f %s   min %9.3f   max %9.3f   (%d runs)\n" "$label" "$med" "$unit" "$min" "$max" "$n"
}

first=() whole=() rss=() cpufirst=() cpuwhole=()
for _ in $(seq "$RUNS"); do
  rm -rf "$STUDY"
  sync
  t0=$(now)
  "${TIME[@]}" "$FLYOVER" run "${INPUT[@]}" --study "$STUDY" --log-json "$@" 2> "$WORK/log.jsonl" || {
    echo "flyover run failed:"; tail -5 "$WORK/log.jsonl"; exit 1; }
  t1=$(now)
  whole+=("$(secs "$t0" "$t1")")
  fp=$(first_pair_seconds "$WORK/log.jsonl")
  [ -n "$fp" ] || { echo "no first_pair event in the log"; exit 1; }
  first+=("$fp")
  cpufirst+=("$(first_pair_cpu "$WORK/log.jsonl")")
  cpuwhole+=("$(last_cpu "$WORK/log.jsonl")")
  [ -f "$WORK/rss" ] && rss+=("$(awk '/^[0-9]+$/ { printf "%.1f", $1 / 1024 }' "$WORK/rss" | tail -1)")
done
echo "flyover run, $SIZE $KIND, cold (fresh study each run), extra arguments: ${*:-none}"
stats "$FROM -> first fly-over pair" s "${first[@]}"
stats "whole run" s "${whole[@]}"
[ ${#rss[@]} -gt 0 ] && stats "peak RSS" MB "${rss[@]}"
stats "process CPU at the first pair" s "${cpufirst[@]}"
stats "process CPU, whole run" s "${cpuwhole[@]}"
rerun=()
for _ in $(seq "$RUNS"); do
  t0=$(now); "$FLYOVER" -q run "${INPUT[@]}" --study "$STUDY" "$@"; t1=$(now)
  rerun+=("$(secs "$t0" "$t1")")
done
stats "unchanged re-run" s "${rerun[@]}"
REFERENCE=${ITK_REFERENCE_BIN:-build/bench/itk_reference}
if [ -z "$CT" ]; then
  echo "no CT: no ITK reference"
elif [ -x "$REFERENCE" ]; then
  "$REFERENCE" "$CT" --runs "$RUNS" | tee "$WORK/reference.txt"
  ref=$(sed -n 's/^reference_seconds //p' "$WORK/reference.txt")
  fpm=$(printf '%s\n' "${first[@]}" | sort -g | awk '{ t[NR] = $1 } END { print (NR % 2 ? t[(NR + 1) / 2] : (t[NR / 2] + t[NR / 2 + 1]) / 2) }')
  awk -v a="$fpm" -v b="$ref" 'BEGIN { printf "first pair / ITK reference: %.3f / %.3f = %.2f (target <= 0.75)\n", a, b, a / b }'
  # The same with ITK's own marching cubes (the pipeline made of ITK alone; slower, 3 runs).
  "$REFERENCE" "$CT" --runs 3 --mesher itk | tee "$WORK/reference-itk.txt"
  refItk=$(sed -n 's/^reference_seconds //p' "$WORK/reference-itk.txt")
  awk -v a="$fpm" -v b="$refItk" 'BEGIN { printf "first pair / ITK-only reference: %.3f / %.3f = %.2f\n", a, b, a / b }'
else
  echo "no $REFERENCE: build it (cmake --build build --target itk_reference) for the ITK reference"
fi
echo "per stage of the last cold run (wall s, computed):"
sed -n 's/.*"event":"stage_finished".*"stage":"\([a-z]*\)".*"wall_seconds":\([0-9.eE+-]*\).*/  \1 \2/p' "$WORK/log.jsonl" ||
  true
