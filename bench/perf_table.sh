#!/usr/bin/env bash
# Re-measures the headline figures and writes them into docs/performance.md's table (between
# the markers <!-- perf_table:begin --> and <!-- perf_table:end -->; the prose around stays).
#
# Usage: bench/perf_table.sh [--size small|medium|full] [--runs N] [--gca] [--view] [--inspect N]
#                            [--build DIR] [--doc FILE] [--print]
#   --size     phantom size (default full: the figures the docs quote)
#   --runs     cold runs per benchmark; the table gives medians (default 5)
#   --gca      also the real colon mask of the shared data (bench/first_pair.sh gca)
#   --view     also the time to the first image in the viewer (bench/first_view.sh)
#   --inspect  also flyover inspect on the N^3 part phantom (bench/inspect_stages.sh N)
#   --build    build folder holding bin/flyover and bench/ (default build)
#   --doc      the file to update (default docs/performance.md)
#   --print    print the table only; write nothing
#
# It runs the existing benchmark scripts, each in a fresh temporary folder (removed at the end
# unless KEEP=1), never in a user's study: bench/first_pair.sh (cold run -> first fly-over
# pair, whole run, peak RSS, process CPU, unchanged re-run, the ITK reference when
# build/bench/itk_reference exists) and, when asked, the others above. Build first
# (scripts/build.sh, Release); run it on a quiet machine: wall times follow the load.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)

usage() { sed -n '5,6p' "$0" | sed 's/^# //'; }
SIZE=full RUNS=5 GCA=0 VIEW=0 INSPECT="" BUILD=build DOC=docs/performance.md PRINT=0
while [ $# -gt 0 ]; do
  case $1 in
    --size) SIZE=${2:?--size needs a value}; shift 2 ;;
    --runs) RUNS=${2:?--runs needs a value}; shift 2 ;;
    --gca) GCA=1; shift ;;
    --view) VIEW=1; shift ;;
    --inspect) INSPECT=${2:?--inspect needs N}; shift 2 ;;
    --build) BUILD=${2:?--build needs a folder}; shift 2 ;;
    --doc) DOC=${2:?--doc needs a file}; shift 2 ;;
    --print) PRINT=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "perf_table.sh: unknown argument '$1'"; usage; exit 2 ;;
  esac
done
case $SIZE in small|medium|full) ;; *) echo "perf_table.sh: --size is small, medium or full, not '$SIZE'"; exit 2 ;; esac
[[ $RUNS =~ ^[1-9][0-9]*$ ]] || { echo "perf_table.sh: --runs must be a positive integer, not '$RUNS'"; exit 2; }
BUILD=$(realpath -m "$BUILD")  # relative to the repository root
FLYOVER=$(realpath -e "$BUILD/bin/flyover" 2> /dev/null) ||
  { echo "perf_table.sh: no $BUILD/bin/flyover: build first (bash scripts/build.sh)"; exit 1; }
BEGIN_MARK='<!-- perf_table:begin -->'
END_MARK='<!-- perf_table:end -->'
if [ "$PRINT" = 0 ]; then
  [ -f "$DOC" ] || { echo "perf_table.sh: no $DOC to update"; exit 1; }
  grep -qF "$BEGIN_MARK" "$DOC" && grep -qF "$END_MARK" "$DOC" ||
    { echo "perf_table.sh: $DOC lacks the markers $BEGIN_MARK and $END_MARK"; exit 1; }
fi

WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-perf-table.XXXXXX")
[ "${KEEP:-0}" = 1 ] && echo "perf_table.sh: keeping $WORK" || trap 'rm -rf "$WORK"' EXIT
LOAD=$(cut -d' ' -f1 /proc/loadavg 2> /dev/null || echo "?")

# bench NAME SCRIPT ARGS...: runs a bench script in its own folder under $WORK, output to NAME.txt.
bench() {
  local name=$1; shift
  echo "== $* ($name)" >&2
  FLYOVER_BIN=$FLYOVER ITK_REFERENCE_BIN="$BUILD/bench/itk_reference" FLYOVER_BENCH_DIR="$WORK/$name" \
    bash "$@" | tee "$WORK/$name.txt" >&2
}
# row FILE LABEL TEXT: the table row of the line of FILE that starts with LABEL, as the bench
# scripts print it ("LABEL median X UNIT min Y max Z (N runs)").
row() {
  local line
  line=$(grep -m1 -F -- "$2" "$1" || true)
  [ -n "$line" ] || { echo "| $3 | (not measured) | | | |"; return; }
  # MB as whole numbers, seconds with three decimals (as measured).
  awk -v text="$3" '{
    for (i = 1; i < NF; i++) {
      if ($i == "median") { med = $(i + 1); unit = $(i + 2) }
      if ($i == "min") min = $(i + 1)
      if ($i == "max") max = $(i + 1)
      if ($i ~ /^\(/) runs = substr($i, 2)
    }
    f = unit == "MB" ? "%.0f" : "%.3f"
    printf "| %s | " f " %s | " f " | " f " | %s |\n", text, med, unit, min, max, runs
  }' <<< "$line"
}
# ratio FILE PREFIX TEXT: the row of first_pair.sh's "PREFIX: a / b = r" line.
ratio() {
  local line
  line=$(grep -m1 -F -- "$2" "$1" || true)
  [ -n "$line" ] || return 0
  # '#' delimits: the row's text holds '/' and '|'.
  sed -E 's#.*: +([0-9.]+) +/ +([0-9.]+) += +([0-9.]+).*#| '"$3"' (reference \2 s) | \3 | | | |#' <<< "$line"
}

bench first-pair bench/first_pair.sh "$SIZE" "$RUNS"
FP=$WORK/first-pair.txt
TABLE=$WORK/table.md
{
  echo "Measured by \`bench/perf_table.sh --size $SIZE --runs $RUNS\` on $(date -u +%Y-%m-%d)," \
       "commit $(git rev-parse --short HEAD 2> /dev/null || echo unknown)," \
       "$(nproc) cores ($(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1)), load average $LOAD at the start."
  echo
  echo "| figure | median | min | max | runs |"
  echo "|---|---|---|---|---|"
  row "$FP" "CT -> first fly-over pair" "$SIZE phantom: CT -> first fly-over pair (cold)"
  row "$FP" "whole run" "$SIZE phantom: whole \`flyover run\` (cold)"
  row "$FP" "peak RSS" "$SIZE phantom: peak RSS of the run"
  row "$FP" "process CPU at the first pair" "$SIZE phantom: process CPU at the first pair"
  row "$FP" "process CPU, whole run" "$SIZE phantom: process CPU, whole run"
  row "$FP" "unchanged re-run" "$SIZE phantom: unchanged re-run (every stage reused)"
  ratio "$FP" "first pair / ITK reference" "first pair / ITK read + threshold + OpenVDB mesh"
  ratio "$FP" "first pair / ITK-only reference" "first pair / ITK read + threshold + ITK marching cubes"
} > "$TABLE"

if [ "$GCA" = 1 ]; then
  bench first-pair-gca bench/first_pair.sh gca "$RUNS"
  G=$WORK/first-pair-gca.txt
  row "$G" "mask -> first fly-over pair" "real colon (gca-colon-00020 mask): mask -> first pair (cold)" >> "$TABLE"
  row "$G" "whole run" "real colon: whole \`flyover run\` (cold)" >> "$TABLE"
  row "$G" "peak RSS" "real colon: peak RSS of the run" >> "$TABLE"
  row "$G" "unchanged re-run" "real colon: unchanged re-run" >> "$TABLE"
  # The real colon against the phantom, medians of this sitting (targets: whole run <= 2x, first pair <= 3x).
  med() { grep -m1 -F -- "$2" "$1" | awk '{ for (i = 1; i < NF; i++) if ($i == "median") { print $(i + 1); exit } }'; }
  for pair in "first pair|mask -> first fly-over pair|CT -> first fly-over pair" "whole run|whole run|whole run"; do
    IFS='|' read -r what gl pl <<< "$pair"
    g=$(med "$G" "$gl") p=$(med "$FP" "$pl")
    [ -n "$g" ] && [ -n "$p" ] &&
      awk -v w="$what" -v g="$g" -v p="$p" -v s="$SIZE" 'BEGIN { printf "| real colon / %s phantom: %s (%.3f / %.3f s) | %.2f | | | |\n", s, w, g, p, g / p }' >> "$TABLE"
  done
fi
if [ "$VIEW" = 1 ]; then
  bench first-view bench/first_view.sh "$SIZE" "$RUNS"
  V=$WORK/first-view.txt
  row "$V" "viewer: study served" "$SIZE phantom, viewer opened with the run: study served" >> "$TABLE"
  row "$V" "viewer: first /api/pair image" "$SIZE phantom, viewer opened with the run: first image" >> "$TABLE"
fi
if [ -n "$INSPECT" ]; then
  bench inspect bench/inspect_stages.sh "$INSPECT"
  awk -v n="$INSPECT" '$1 == "total" { printf "| `flyover inspect`, %s^3 part phantom, stage by stage: wall %s s, CPU %s s, peak %s MB | %s s | | | 1 |\n", n, $2, $3, $4, $2 }
                       $1 == "unchanged" { printf "| `flyover inspect`, %s^3 part phantom: unchanged re-run | %s s | | | 1 |\n", n, $2 }' \
    "$WORK/inspect.txt" >> "$TABLE"
fi

if [ "$PRINT" = 1 ]; then
  cat "$TABLE"
  exit 0
fi
# Replace what lies between the markers; write a temporary file beside the doc, then rename.
NEW="$DOC.perf_table.tmp"
awk -v table="$TABLE" -v begin="$BEGIN_MARK" -v end="$END_MARK" '
  $0 == begin { print; while ((getline l < table) > 0) print l; skip = 1; next }
  $0 == end { skip = 0 }
  !skip { print }' "$DOC" > "$NEW"
mv "$NEW" "$DOC"
echo "perf_table.sh: wrote the table of $DOC" >&2
cat "$TABLE"
