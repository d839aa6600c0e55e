#!/usr/bin/env bash
# Runs two builds of flyover on the same inputs and compares every artifact's bytes: a change
# that must not change results (a move, a refactor) is checked with it.
#   scripts/compare_builds.sh OLD_FLYOVER NEW_FLYOVER [UNTIL]
# Inputs: the small phantom (CT, seed 1), its truth mask alone, and the real gca-colon-00020 mask
# when ../shared/data is present. UNTIL (default: all stages) is passed as --until. Works in a
# fresh temporary folder, removed at the end. Exit 0: every artifact identical; 1: a difference
# (listed); 2: a run failed.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: $0 OLD_FLYOVER NEW_FLYOVER [UNTIL]" >&2; exit 2; }
OLD=$(realpath "$1"); NEW=$(realpath "$2"); UNTIL=${3:-}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-compare.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
until_args=(); [ -n "$UNTIL" ] && until_args=(--until "$UNTIL")
"$NEW" phantom "$WORK/ct.nii.gz" --truth "$WORK/truth.json" --truth-mask "$WORK/mask.nii.gz" --size small --seed 1 >/dev/null
inputs=("ct:$WORK/ct.nii.gz" "mask:--mask $WORK/mask.nii.gz")
GCA="$ROOT/../shared/data/real/gca-colon-00020/large_intestine.nii.gz"
[ -f "$GCA" ] && inputs+=("gca:--mask $GCA")
# Artifacts only: the manifest and logs hold wall times; the cache holds the same bytes again.
digests() { (cd "$1" && find . -path ./.flyover -prune -o -type f ! -name manifest.json ! -name '*.log' -print \
               | sort | xargs sha256sum); }
status=0
for entry in "${inputs[@]}"; do
  name=${entry%%:*}; args=${entry#*:}
  for which in old new; do
    bin=$OLD; [ $which = new ] && bin=$NEW
    # shellcheck disable=SC2086
    "$bin" run $args --study "$WORK/$name-$which" "${until_args[@]}" >"$WORK/$name-$which.out" 2>&1 \
      || { echo "$name: the $which build's run failed:"; tail -3 "$WORK/$name-$which.out"; exit 2; }
  done
  if diff <(digests "$WORK/$name-old") <(digests "$WORK/$name-new") >"$WORK/$name.diff"; then
    echo "$name: $(digests "$WORK/$name-new" | wc -l) artifacts identical"
  else
    echo "$name: artifacts differ:"; cat "$WORK/$name.diff"; status=1
  fi
done
exit $status
