#!/usr/bin/env bash
# flyover inspect at scale: per stage, wall time, CPU time (user + sys) and peak RSS,
# on the part phantom of N^3 voxels (uint16, written streaming).
# Usage: bench/inspect_stages.sh [N=512] [time limit per stage, s=900] [extra inspect arguments...]
# Each stage runs as its own process (`flyover inspect --until STAGE`, the stages before it
# reused from the cache), so its peak RSS includes reading its inputs back from the study;
# then one more unchanged run (everything reused). The sum of the stages is the end-to-end
# figure (a single `flyover inspect` keeps the grids in memory between stages instead of
# reading them back: a little faster). Works only in its own folder (FLYOVER_BENCH_DIR,
# default /tmp/flyover-bench-inspect): the 1024^3 phantom takes 2 GB there and the study
# about 6 GB; about 7 GB of memory. Build first: scripts/build.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
N=${1:-512}
LIMIT=${2:-900}
shift $(( $# < 2 ? $# : 2 ))
FLYOVER=$(realpath "${FLYOVER_BIN:-build/bin/flyover}")
WORK=${FLYOVER_BENCH_DIR:-/tmp/flyover-bench-inspect}
mkdir -p "$WORK"
CT="$WORK/part-$N.nii"
if [ ! -f "$CT" ]; then
  /usr/bin/time -f "phantom %e s wall, %U+%S s CPU, peak %M KB" -o "$WORK/phantom.time" \
    timeout "$LIMIT" "$FLYOVER" -q phantom "$CT" --part --size "$N" --truth "$WORK/part-$N.json"
  cat "$WORK/phantom.time"
fi
STUDY="$WORK/study-$N"
rm -rf "$STUDY"
printf '%-10s %9s %9s %9s\n' stage "wall s" "CPU s" "peak MB"
total_wall=0 total_cpu=0 peak=0
for stage in ingest voids surfaces overviews turntable; do
  if ! /usr/bin/time -f "%e %U %S %M" -o "$WORK/stage.time" timeout "$LIMIT" \
      "$FLYOVER" inspect "$CT" --study "$STUDY" --until "$stage" --quiet "$@"; then
    echo "$stage: failed or over ${LIMIT} s"; exit 1
  fi
  read -r wall user sys rss < "$WORK/stage.time"
  cpu=$(awk -v u="$user" -v s="$sys" 'BEGIN { printf "%.1f", u + s }')
  printf '%-10s %9.1f %9s %9d\n' "$stage" "$wall" "$cpu" $(( rss / 1024 ))
  total_wall=$(awk -v a="$total_wall" -v b="$wall" 'BEGIN { print a + b }')
  total_cpu=$(awk -v a="$total_cpu" -v b="$cpu" 'BEGIN { print a + b }')
  [ "$rss" -gt "$peak" ] && peak=$rss
done
printf '%-10s %9.1f %9.1f %9d\n' total "$total_wall" "$total_cpu" $(( peak / 1024 ))
/usr/bin/time -f "%e %U %S %M" -o "$WORK/stage.time" "$FLYOVER" inspect "$CT" --study "$STUDY" --quiet "$@"
read -r wall user sys rss < "$WORK/stage.time"
printf '%-10s %9.1f %9.1f %9d\n' unchanged "$wall" "$(awk -v u="$user" -v s="$sys" 'BEGIN { print u + s }')" $(( rss / 1024 ))
python3 - "$STUDY" <<'PY' || true
import json, sys
study = sys.argv[1]
v = json.load(open(study + "/voids.json"))
s = json.load(open(study + "/surfaces.json"))
vis = json.load(open(study + "/overviews/visibility.json"))
print(f"voids {v['listed_void_count']} listed, porosity {v['porosity_percent']:.4f} %; "
      f"surface {s['faces']} faces ({s['outer']['faces']} outer); "
      f"voids unseen in every OST overview {vis['voids_unseen_in_ost']}, seen in a normal render {vis['voids_seen_in_normal']}")
PY
