#!/usr/bin/env bash
# CTest: workflows/cohort/Snakefile on three small phantoms (two CTs, one mask-only) and one
# corrupt scan, with --cores 2:
#   1. the three studies complete, the corrupt scan is a "failed" row naming its file and cause;
#   2. a second invocation does nothing ("Nothing to be done", cohort.csv untouched);
#   3. a changed render parameter re-runs exactly the render jobs (and the report), and flyover
#      recomputes only its render stage.
# Usage: cohort_workflow_test.sh FLYOVER_BIN SNAKEFILE.   Exit 77 (skipped) without snakemake.
set -uo pipefail

FLYOVER=$1
SNAKEFILE=$2
if ! command -v snakemake >/dev/null 2>&1; then
  echo "SKIPPED: snakemake is not installed (Debian: apt-get install snakemake; scripts/setup.sh installs it)"
  exit 77
fi

WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-cohort-test.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
cd "$WORK" || exit 1
fails=0
T0=$(date +%s)
phase() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
check() {  # check DESCRIPTION EXPECTED SEEN
  if [ "$2" == "$3" ]; then echo "ok: $1"; else echo "FAIL: $1: expected '$2', saw '$3'"; fails=$((fails + 1)); fi
}

phase "phantoms"
# Inputs: phantoms with different seeds; scan 3 is given by its true lumen mask alone.
mkdir -p scans
"$FLYOVER" -q phantom scans/p1.nii.gz --truth scans/p1.json --size small --seed 11 || exit 1
"$FLYOVER" -q phantom scans/p2.nii.gz --truth scans/p2.json --size small --seed 12 --collapse || exit 1
"$FLYOVER" -q phantom scans/p3.nii.gz --truth scans/p3.json --size small --seed 13 --truth-mask scans/p3-mask.nii.gz || exit 1
head -c 200000 scans/p1.nii.gz > scans/broken.nii.gz   # truncated gzip stream
{
  printf 'id\tct\tmask\tset\n'
  printf 'p1\tp1.nii.gz\t\t\n'
  printf 'p2\tp2.nii.gz\t\tcenterline.step_mm=1.5\n'
  printf 'p3\t\tp3-mask.nii.gz\t\n'
  printf 'broken\tbroken.nii.gz\t\t\n'
} > scans/scans.tsv

# Small and quick renders: no video, coarse coverage, tiny frames.
RENDER="render.video=false render.width_px=64 render.height_px=64 render.frame_step_mm=200 render.overview_px=128 render.flythrough_frames=false render.coverage_px=32 render.coverage_step_mm=25"
smk() {  # smk RENDER_PARAMS [snakemake options...]
  local render=$1; shift
  snakemake -s "$SNAKEFILE" --cores 2 --config scans=scans/scans.tsv out=cohort flyover="$FLYOVER" \
    render="$render" "$@"
}
# "rule: count" lines of Snakemake's "Job stats" table, sorted, one line.
jobstats() { awk '/^Job stats:/{on=1; next} on && /^total/{exit} on && NF==4 && $2 ~ /^[0-9]+$/ {print $1":"$2}' "$1" | sort | tr '\n' ' '; }

# 1. The first run, without --keep-going: the corrupt scan must not stop the others.
phase "first run"
smk "$RENDER" > run1.log 2>&1
rc=$?
phase "first run done"
check "first snakemake run exits 0" 0 "$rc"
[ "$rc" -eq 0 ] || tail -n 40 run1.log
check "cohort.csv: header + 4 rows" 5 "$(wc -l < cohort/cohort.csv)"
# The report, read once (one python start per check is slow on a busy machine): "id<TAB>column<TAB>value" lines.
python3 - > rows.tsv <<'EOF'
import csv
for r in csv.DictReader(open("cohort/cohort.csv")):
    for k, v in r.items():
        print(f"{r['id']}\t{k}\t{v}")
EOF
row() { awk -F'\t' -v id="$1" -v col="$2" '$1 == id && $2 == col {print $3; found=1} END {if (!found) print "<no such row or column>"}' rows.tsv; }
# between LOW HIGH VALUE: "yes" when LOW < VALUE <= HIGH (a number), else "no: VALUE"
between() { awk -v lo="$1" -v hi="$2" -v v="$3" 'BEGIN {print (v ~ /^[0-9.eE+-]+$/ && v + 0 > lo && v + 0 <= hi) ? "yes" : "no: " v}'; }
for id in p1 p2 p3; do
  check "$id: status" ok "$(row $id status)"
  check "$id: error" "" "$(row $id error)"
  check "$id: lumen volume in (100, 10000] mL" yes "$(between 100 10000 "$(row $id lumen_volume_ml)")"
  check "$id: centerline length in (500, 3000] mm" yes "$(between 500 3000 "$(row $id centerline_length_mm)")"
  check "$id: fly-over coverage in (0.9, 1]" yes "$(between 0.9 1 "$(row $id coverage_flyover)")"
  check "$id: overview thumbnail in the HTML" 1 "$(grep -c "<img src=\"studies/$id/overview.png\"" cohort/cohort.html)"
  check "$id: render receipt ok" 1 "$(grep -c '"status": "ok"' cohort/studies/$id/stages/render.json)"
done
check "p2 (collapsed sigmoid): collapses in [1, 3]" yes "$(between 0.5 3 "$(row p2 collapses)")"
check "p3 is mask-only: no ingest job ran" no "$( [ -e cohort/studies/p3/stages/ingest.json ] && echo yes || echo no)"
check "broken: status" failed "$(row broken status)"
check "broken: failed at" ingest "$(row broken failed_stage)"
err=$(row broken error)
echo "broken: error = $err"
check "broken: the error names the file" yes "$(case "$err" in *broken.nii.gz*) echo yes;; *) echo no;; esac)"
check "broken: the error is one line" 1 "$(printf '%s\n' "$err" | wc -l)"
check "broken: no overview in its row" "" "$(row broken overview)"
check "broken: its later stages failed at once with the same cause" yes "$(grep -q 'ingest failed earlier' cohort/studies/broken/stages/render.json && echo yes || echo no)"

# 2. A second invocation does nothing.
phase "second invocation"
before=$(stat -c %Y cohort/cohort.csv)
smk "$RENDER" > run2.log 2>&1
check "second invocation exits 0" 0 "$?"
check "second invocation: nothing to be done" 1 "$(grep -c 'Nothing to be done' run2.log)"
check "second invocation: cohort.csv untouched" "$before" "$(stat -c %Y cohort/cohort.csv)"

receipts() { stat -c '%n %Y' cohort/studies/$1/stages/{ingest,segment,centerline,mesh}.json 2>/dev/null | tr '\n' ' '; }
for id in p1 p2 p3; do receipts $id > receipts-$id.txt; done
sleep 1

# 3. One render parameter changed: only the render jobs (and the report) re-run.
RENDER2="${RENDER/render.coverage_px=32/render.coverage_px=40}"
phase "render change"
# The stages the last flyover call computed, from a study's manifest.
computed_in_manifest() {
  python3 -c 'import json, sys; m = json.load(open(sys.argv[1])); print(" ".join(s["stage"] for s in m["stages"] if s["computed"]))' \
    "cohort/studies/$1/manifest.json"
}
smk "$RENDER2" > run3.log 2>&1
check "render change: run exits 0" 0 "$?"
check "render change: jobs run" "all:1 render:4 report:1 " "$(jobstats run3.log)"
for id in p1 p2 p3; do
  # render.coverage_px is a parameter of the render's coverage step alone: only that step is
  # recomputed (frames, fly-through, overviews and video are reused from the study's cache).
  check "$id: flyover computed the coverage step, reused the rest" "coverage" "$(computed_in_manifest $id)"
  check "$id: receipts of the other stages untouched" "$(cat receipts-$id.txt)" "$(receipts $id)"
done
phase "render change done"
check "render change: second invocation does nothing" 1 "$(smk "$RENDER2" -n 2>&1 | grep -c 'Nothing to be done')"

phase "end"
if [ "$fails" -ne 0 ]; then
  echo "$fails check(s) failed; logs:"
  for f in run1.log run3.log; do echo "== $f"; tail -n 30 "$f"; done
  exit 1
fi
echo "all checks passed"
