#!/usr/bin/env bash
# bench/perf_table.sh --print on the small phantom, one run: the table has its rows, the ITK
# reference ratios among them (their text holds '/' and '|'), and nothing "not measured".
# Usage: perf_table_test.sh SOURCE_DIR BUILD_DIR
set -euo pipefail
ROOT=$1 BUILD=$2
fail() { echo "FAIL: $*" >&2; exit 1; }
rc=0
out=$(bash "$ROOT/bench/perf_table.sh" --size small --runs 1 --print --build "$BUILD" 2> /dev/null) || rc=$?
[ "$rc" -eq 0 ] || fail "expected perf_table.sh to exit 0, it exited $rc; it printed: $(tail -3 <<<"$out")"
for row in "| small phantom: CT -> first fly-over pair (cold) | " "| small phantom: whole \`flyover run\` (cold) | " \
           "| first pair / ITK read + threshold + OpenVDB mesh (reference " \
           "| first pair / ITK read + threshold + ITK marching cubes (reference "; do
  grep -qF -- "$row" <<<"$out" || fail "expected a row starting '$row'; the table was: $out"
done
! grep -q "not measured" <<<"$out" || fail "a row was not measured: $(grep "not measured" <<<"$out")"
echo "perf_table.sh printed every row"
