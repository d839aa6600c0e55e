#!/usr/bin/env bash
# CTest: how workflows/cohort/Snakefile treats flyover's exit codes, with a stand-in for the
# flyover program (the real one is exercised by cohort_workflow_test.sh; this one makes the
# failures happen on purpose, in seconds):
#   exit 75 (temporary) fails the job, so without --retries the workflow stops with an error, and
#   with --retries 1 the job runs again and the cohort completes;
#   exit 1 (bad scan, "failed" receipt written) never fails the job: the scan is a failed row.
# Usage: cohort_exit_codes_test.sh SNAKEFILE.   Exit 77 (skipped) without snakemake.
set -uo pipefail

SNAKEFILE=$1
if ! command -v snakemake >/dev/null 2>&1; then
  echo "SKIPPED: snakemake is not installed (Debian: apt-get install snakemake; scripts/setup.sh installs it)"
  exit 77
fi
WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-cohort-codes.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
cd "$WORK" || exit 1
fails=0
check() {
  if [ "$2" == "$3" ]; then echo "ok: $1"; else echo "FAIL: $1: expected '$2', saw '$3'"; fails=$((fails + 1)); fi
}

# The stand-in: `flyover --threads N stage NAME --study DIR [--ct CT] ...` as the Snakefile calls
# it. An empty CT is a bad scan (exit 1 and a failed receipt, like flyover); the first render of
# each study fails with exit 75 (as a full disk would), the next one succeeds.
cat > fake-flyover <<'EOF'
#!/usr/bin/env bash
[ "$1" = "--threads" ] && shift 2
[ "$1" = "stage" ] || { echo "fake-flyover: unexpected command: $*" >&2; exit 2; }
name=$2; shift 2; study=""; ct=""
while [ $# -gt 0 ]; do
  case $1 in --study) study=$2; shift 2;; --ct) ct=$2; shift 2;; --mask|--set) shift 2;; *) shift;; esac
done
mkdir -p "$study/stages"
if [ -n "$ct" ] && [ ! -s "$ct" ]; then
  printf '{"status": "failed", "exit_code": 1, "error": "%s: %s: empty file"}\n' "$name" "$ct" > "$study/stages/$name.json"
  echo "flyover: error: $name: $ct: empty file" >&2
  exit 1
fi
if [ "$name" = render ] && [ ! -e "$study/render-tried" ]; then
  touch "$study/render-tried"
  echo "flyover: error: render: frames/pair_0001.png: cannot write: No space left on device" >&2
  exit 75
fi
printf '{"status": "ok", "exit_code": 0, "computed": true}\n' > "$study/stages/$name.json"
EOF
chmod +x fake-flyover
mkdir -p scans
echo scan > scans/a.nii.gz
: > scans/empty.nii.gz
printf 'id\tct\na\ta.nii.gz\nempty\tempty.nii.gz\n' > scans/scans.tsv
smk() { snakemake -s "$SNAKEFILE" --cores 2 --config scans=scans/scans.tsv out=cohort flyover="$PWD/fake-flyover" "$@"; }

smk > run1.log 2>&1
check "exit 75 without --retries fails the workflow" 1 "$?"
check "the failing job says it will be retried with --retries" 1 "$(grep -c 'flyover stage render on a exited 75' run1.log)"
check "no report after a failed job" no "$([ -e cohort/cohort.csv ] && echo yes || echo no)"

rm -rf cohort .snakemake
smk --retries 1 > run2.log 2>&1
check "with --retries 1 the workflow completes" 0 "$?"
check "a: ok after the retry" "a,ok" "$(grep '^a,' cohort/cohort.csv | cut -d, -f1-2)"
check "empty: a failed row naming the file (exit 1 never fails a job)" "empty,failed,ingest" \
  "$(grep '^empty,' cohort/cohort.csv | cut -d, -f1-3)"
check "empty: its error" 1 "$(grep -c '^empty,.*empty.nii.gz: empty file' cohort/cohort.csv)"

if [ "$fails" -ne 0 ]; then
  for f in run1.log run2.log; do echo "== $f"; tail -n 25 "$f"; done
  exit 1
fi
echo "all checks passed"
