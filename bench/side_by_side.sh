#!/usr/bin/env bash
# Two builds of flyover timed side by side: cold `flyover run`s alternated old, new, old, new...
# so that the machine's load hits both alike. Prints per build the median / min / max of the
# first fly-over pair (the "first_pair" event), the whole run and the process CPU, and new / old.
#   bench/side_by_side.sh OLD_FLYOVER NEW_FLYOVER [small|medium|full|gca] [runs] [run arguments...]
# Run arguments go to both builds' `flyover run` (e.g. --until frames: the first pair alone).
# gca: the real colon mask of the shared data (gca-colon-00020, --mask). Works only in its own
# folder (FLYOVER_BENCH_DIR, default a fresh temporary one, removed at the end): never in a
# user's study. scripts/compare_builds.sh checks that the two give the same bytes.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: $0 OLD_FLYOVER NEW_FLYOVER [small|medium|full|gca] [runs] [run arguments...]" >&2; exit 2; }
OLD=$(realpath -e "$1") NEW=$(realpath -e "$2") SIZE=${3:-full} RUNS=${4:-3}
shift $(( $# < 4 ? $# : 4 ))
EXTRA=("$@")
[[ $RUNS =~ ^[1-9][0-9]*$ ]] || { echo "side_by_side.sh: runs must be a positive integer, not '$RUNS'" >&2; exit 2; }
cd "$(dirname "$0")/.."
ROOT=$(pwd)
WORK=${FLYOVER_BENCH_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/flyover-side-by-side.XXXXXX")}
[ -n "${FLYOVER_BENCH_DIR:-}" ] || trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK"
case $SIZE in
  gca)
    . bench/shared_data.sh
    INPUT=(--mask "$(shared_data)/real/gca-colon-00020/large_intestine.nii.gz")
    [ -f "${INPUT[1]}" ] || { echo "side_by_side.sh: no ${INPUT[1]}: the gca mode needs the shared real data" >&2; exit 1; } ;;
  small|medium|full)
    INPUT=("$WORK/phantom-$SIZE.nii.gz")
    "$NEW" -q phantom "${INPUT[0]}" --truth "$WORK/phantom-$SIZE.json" --size "$SIZE" ;;
  *) echo "side_by_side.sh: the input is small, medium, full or gca, not '$SIZE'" >&2; exit 2 ;;
esac

. bench/run_log.sh
# run WHICH BIN: one cold run; appends "first whole cpu" to $WORK/WHICH.txt.
run() {
  local which=$1 bin=$2 t0 t1 fp cpu
  rm -rf "$WORK/study"
  sync
  t0=$(now)
  "$bin" run "${INPUT[@]}" --study "$WORK/study" --log-json "${EXTRA[@]}" 2> "$WORK/log.jsonl" ||
    { echo "side_by_side.sh: the $which build's run failed:" >&2; tail -3 "$WORK/log.jsonl" >&2; exit 1; }
  t1=$(now)
  fp=$(first_pair_seconds "$WORK/log.jsonl")
  cpu=$(last_cpu "$WORK/log.jsonl")
  echo "${fp:-nan} $(secs "$t0" "$t1") ${cpu:-nan}" >> "$WORK/$which.txt"
}
rm -f "$WORK/old.txt" "$WORK/new.txt"
for _ in $(seq "$RUNS"); do
  run old "$OLD"
  run new "$NEW"
done
# column FILE N: median min max of column N.
column() { awk -v c="$2" '{ print $c }' "$1" | median_min_max; }
echo "side by side, $SIZE (${INPUT[*]##*/}), $RUNS cold runs each, alternated, run arguments: ${EXTRA[*]:-none}; old $OLD, new $NEW"
printf '%-22s %28s %28s %9s\n' "" "old: median (min max)" "new: median (min max)" "new/old"
n=0
for what in "first fly-over pair" "whole run" "process CPU"; do
  n=$((n + 1))
  read -r om omin omax _ <<< "$(column "$WORK/old.txt" $n)"
  read -r nm nmin nmax _ <<< "$(column "$WORK/new.txt" $n)"
  printf '%-22s %9.3f s (%7.3f %7.3f) %9.3f s (%7.3f %7.3f) %9.3f\n' "$what" "$om" "$omin" "$omax" "$nm" "$nmin" "$nmax" \
    "$(awk -v a="$nm" -v b="$om" 'BEGIN { printf "%.3f", a / b }')"
done
