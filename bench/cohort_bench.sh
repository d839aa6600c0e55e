#!/usr/bin/env bash
# Wall time of a cohort: workflows/cohort/Snakefile with --cores C (jobs side by side, one
# thread each) against the same scans run one after another (`flyover --threads C run`, each
# scan using every core). Small phantoms (seeds 1..N), fresh studies for each mode, on copies
# under a temporary folder; quick renders (no video, coarse coverage) unless RENDER is set.
#
#   bench/cohort_bench.sh [N=8] [C=2]          (from the repository root, after a build)
#   FLYOVER=build/bin/flyover RENDER="render.video=false" KEEP=1 bench/cohort_bench.sh
set -euo pipefail

N=${1:-8}
CORES=${2:-2}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
FLYOVER=$(realpath "${FLYOVER:-$ROOT/build/bin/flyover}")
SNAKEFILE=$ROOT/workflows/cohort/Snakefile
RENDER=${RENDER:-render.video=false render.width_px=128 render.height_px=128 render.overview_px=256 render.coverage_px=48 render.coverage_step_mm=10}
command -v snakemake >/dev/null || { echo "cohort_bench: snakemake is not installed" >&2; exit 1; }
[ -x "$FLYOVER" ] || { echo "cohort_bench: $FLYOVER: no flyover program (build first, or set FLYOVER)" >&2; exit 1; }

WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-cohort-bench.XXXXXX")
[ -n "${KEEP:-}" ] || trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK/scans"
printf 'id\tct\n' > "$WORK/scans/scans.tsv"
for i in $(seq 1 "$N"); do
  "$FLYOVER" -q phantom "$WORK/scans/p$i.nii.gz" --truth "$WORK/scans/p$i.json" --size small --seed "$i"
  printf 'p%d\tp%d.nii.gz\n' "$i" "$i" >> "$WORK/scans/scans.tsv"
done
sets=()
for a in $RENDER; do sets+=(--set "$a"); done

now() { date +%s.%N; }
echo "cohort_bench: $N small phantoms, $CORES cores, $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "render: $RENDER"

t0=$(now)
for i in $(seq 1 "$N"); do
  "$FLYOVER" -q --threads "$CORES" run "$WORK/scans/p$i.nii.gz" --study "$WORK/seq/p$i" "${sets[@]}"
done
t1=$(now)
seq_s=$(echo "$t1 - $t0" | bc)

t0=$(now)
(cd "$WORK" && snakemake -s "$SNAKEFILE" --cores "$CORES" --quiet \
   --config scans=scans/scans.tsv out=cohort flyover="$FLYOVER" render="$RENDER" > snakemake.log 2>&1) ||
  { tail -n 30 "$WORK/snakemake.log"; exit 1; }
t1=$(now)
smk_s=$(echo "$t1 - $t0" | bc)
ok=$(awk -F, 'NR>1 && $2=="ok"' "$WORK/cohort/cohort.csv" | wc -l)

printf 'one after another (flyover --threads %d run): %8.1f s\n' "$CORES" "$seq_s"
printf 'snakemake --cores %d:                          %8.1f s  (%d/%d scans ok)\n' "$CORES" "$smk_s" "$ok" "$N"
printf 'speed-up: %.2f\n' "$(echo "$seq_s / $smk_s" | bc -l)"
[ -z "${KEEP:-}" ] || echo "kept: $WORK"
