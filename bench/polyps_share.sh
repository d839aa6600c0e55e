#!/usr/bin/env bash
# The polyps stage's share of a whole run: full-size phantoms (seeds 1..N, default 3), each run
# fresh in a temporary folder, the stage's wall time over the run's wall time from the
# manifest; prints each and the median. Target: at most 15% on the full phantom.
#
#   bench/polyps_share.sh [N=3]            (from the repository root, after a build)
#   FLYOVER=build/bin/flyover SIZE=medium bench/polyps_share.sh 5
set -euo pipefail

N=${1:-3}
SIZE=${SIZE:-full}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
FLYOVER=$(realpath "${FLYOVER:-$ROOT/build/bin/flyover}")
[ -x "$FLYOVER" ] || { echo "polyps_share: $FLYOVER: no flyover program (build first, or set FLYOVER)" >&2; exit 1; }
WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-polyps-bench.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
echo "polyps_share: $N $SIZE phantoms, $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
shares=()
for i in $(seq 1 "$N"); do
  "$FLYOVER" -q phantom "$WORK/p$i.nii.gz" --truth "$WORK/p$i.json" --size "$SIZE" --seed "$i"
  t0=$(date +%s.%N)
  "$FLYOVER" -q run "$WORK/p$i.nii.gz" --study "$WORK/s$i"
  t1=$(date +%s.%N)
  stage=$(python3 -c "import json,sys; m=json.load(open(sys.argv[1])); print([s for s in m['stages'] if s['stage']=='polyps'][0]['wall_seconds'])" "$WORK/s$i/manifest.json")
  whole=$(echo "$t1 - $t0" | bc)
  share=$(echo "scale=4; $stage / $whole" | bc)
  printf 'seed %d: whole run %.1f s, polyps %.2f s, share %.3f\n' "$i" "$whole" "$stage" "$share"
  shares+=("$share")
  rm -rf "$WORK/s$i" "$WORK/p$i.nii.gz"
done
printf '%s\n' "${shares[@]}" | sort -n | awk '{a[NR]=$1} END {printf "median share %.3f (target <= 0.15)\n", a[int((NR+1)/2)]}'
