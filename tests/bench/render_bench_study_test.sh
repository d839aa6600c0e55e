#!/usr/bin/env bash
# render_bench --study on a CT study and on a mask-only study (whose manifest records no CT:
# "input" is null): the bench reads both, times the first pair on a copy, and leaves the study
# as it was (the same manifest and no new files).
# Usage: render_bench_study_test.sh FLYOVER RENDER_BENCH
set -euo pipefail
FLYOVER=$1 BENCH=$2
WORK=$(mktemp -d /tmp/flyover-render-bench-test.XXXXXX)
trap 'rm -rf "$WORK"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }

"$FLYOVER" -q phantom "$WORK/ct.nii.gz" --truth "$WORK/truth.json" --truth-mask "$WORK/mask.nii.gz" --size small --seed 1
"$FLYOVER" -q run "$WORK/ct.nii.gz" --study "$WORK/ct-study" --until frames
"$FLYOVER" -q run --mask "$WORK/mask.nii.gz" --study "$WORK/mask-study" --until frames

for study in ct-study mask-study; do
  dir="$WORK/$study"
  before=$(cd "$dir" && find . -type f | sort | xargs md5sum)
  rc=0
  out=$("$BENCH" --mode speed --study "$dir" --runs 1 --positions 2 --px 32 2>&1) || rc=$?
  [ "$rc" -eq 0 ] || fail "$study: expected render_bench to exit 0, it exited $rc: $(grep -m1 'render_bench:' <<<"$out")"
  grep -q "time from the cached surface and centerline to the first saved pair" <<<"$out" \
    || fail "$study: expected the first-pair timing line; the bench printed: $(grep -v '^$' <<<"$out" | tail -3)"
  after=$(cd "$dir" && find . -type f | sort | xargs md5sum)
  [ "$before" = "$after" ] || fail "$study: the bench changed the study: $(diff <(echo "$before") <(echo "$after") | head -5)"
done
echo "render_bench read the CT study and the mask-only study and left both as they were"
