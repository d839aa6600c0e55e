#!/usr/bin/env bash
# The CT path and the mask path on the same colon (the mask-only segment stage should come near
# the CT path's 3 s, a figure taken on the phantom's ~1 L colon). Makes a CT of the mask with
# build/bench/mask_to_ct, then times cold runs (fresh study each) of
#   ct      flyover run CT --study S --until segment            (ingest + segment)
#   mask    flyover run --mask MASK --study S --until segment   (the mask path on the mask as given)
#   padded  flyover run --mask PADDED --study S --until segment (the same, on the CT's field)
# alternating the three in each round: wall, CPU user + sys and peak RSS (GNU time), and the
# ingest and segment stages' wall seconds (the run log); medians, min, max. Then the lumens: volume
# (segment report), pieces, contacts cut, and the Dice of the lumens exported on the CT's field
# (CT path against the padded mask path and both against the input mask); and when the mask has a
# reference path beside it (reference_path.json, as gca-colon-00020), the centerline of the CT's
# and of the mask's lumen against it (build/bench/centerline_real: length ratio, mean / p95 error).
#
# Usage: bench/mask_vs_ct.sh [MASK] [RUNS]
#   MASK  default: shared/data/real/gca-colon-00020/large_intestine.nii.gz; RUNS default 3
#   env   PAD_MM (10: the CT's field is the mask's widened by that much on every side, on the same
#         lattice: a mask cropped to the organ touches its field's edge, where the CT path takes air
#         for the air outside the body), LABEL (the mask's lumen label; default every non-zero
#         voxel), PADDED (1; 0 leaves out the padded mask's runs), REF (reference path JSON),
#         FLYOVER_BIN, MASK_TO_CT_BIN, CENTERLINE_REAL_BIN, FLYOVER_BENCH_DIR
# Works only in its own folder (FLYOVER_BENCH_DIR, default /tmp/flyover-bench-mask-vs-ct): never in
# a user's study. Build first: scripts/build.sh. Needs GNU time (/usr/bin/time) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
. "$ROOT/bench/shared_data.sh"
MASK=${1:-$(shared_data)/real/gca-colon-00020/large_intestine.nii.gz}
RUNS=${2:-3}
PAD_MM=${PAD_MM:-10}
PADDED=${PADDED:-1}
FLYOVER=${FLYOVER_BIN:-build/bin/flyover}
TOCT=${MASK_TO_CT_BIN:-build/bench/mask_to_ct}
CLREAL=${CENTERLINE_REAL_BIN:-build/bench/centerline_real}
WORK=${FLYOVER_BENCH_DIR:-/tmp/flyover-bench-mask-vs-ct}
REF=${REF:-$(dirname "$MASK")/reference_path.json}
for f in "$FLYOVER" "$TOCT"; do
  [ -x "$f" ] || { echo "mask_vs_ct: $f: not built (scripts/build.sh)" >&2; exit 1; }
done
[ -f "$MASK" ] || { echo "mask_vs_ct: $MASK: no such mask" >&2; exit 1; }
[ -x /usr/bin/time ] || { echo "mask_vs_ct: /usr/bin/time (GNU time) is needed" >&2; exit 1; }
command -v python3 > /dev/null || { echo "mask_vs_ct: python3 is needed" >&2; exit 1; }
case "$RUNS" in ''|*[!0-9]*|0) echo "mask_vs_ct: RUNS: expected a whole number >= 1, got \"$RUNS\"" >&2; exit 1 ;; esac
labelArgs=()
[ -n "${LABEL:-}" ] && labelArgs=(--label "$LABEL")
mkdir -p "$WORK"
MASK=$(realpath "$MASK")

# The CT (and the mask on its field), made again only when the mask or the options change.
CT=$WORK/ct.nii.gz
PADMASK=$WORK/mask-padded.nii.gz
key="$MASK $(stat -c '%s %Y' "$MASK") pad $PAD_MM label ${LABEL:-0} $(stat -c '%Y' "$TOCT")"
if [ ! -f "$CT" ] || [ ! -f "$PADMASK" ] || [ "$(cat "$WORK/ct.key" 2> /dev/null)" != "$key" ]; then
  rm -f "$WORK/ct.key"
  "$TOCT" "$MASK" "$CT" --pad-mm "$PAD_MM" --mask-out "$PADMASK" "${labelArgs[@]}"
  echo "$key" > "$WORK/ct.key"
fi

now() { date +%s%N; }
median_min_max() {  # values... -> "median min max"
  printf '%s\n' "$@" | sort -g | awk '{ t[NR] = $1 }
    END { printf "%.2f %.2f %.2f", (NR % 2 ? t[(NR + 1) / 2] : (t[NR / 2] + t[NR / 2 + 1]) / 2), t[1], t[NR] }'
}
variants=(ct mask)
[ "$PADDED" != 0 ] && variants+=(padded)
declare -A vals
echo "mask_vs_ct: $MASK, $RUNS cold runs each of ${variants[*]}, --until segment; $(nproc) CPUs, load at start $(cut -d' ' -f1-3 /proc/loadavg)"
for _ in $(seq "$RUNS"); do
  for v in "${variants[@]}"; do
    case $v in
      ct) input=("$CT") ;;
      mask) input=(--mask "$MASK" "${labelArgs[@]}") ;;
      padded) input=(--mask "$PADMASK") ;;
    esac
    study=$WORK/study-$v
    rm -rf "$study"
    sync
    /usr/bin/time -f "%e %U %S %M" -o "$WORK/time" "$FLYOVER" run "${input[@]}" --study "$study" --until segment \
      --log-json 2> "$WORK/log-$v.jsonl" || { echo "mask_vs_ct: flyover run ($v) failed:"; grep -v progress "$WORK/log-$v.jsonl" | tail -3; exit 1; }
    read -r wall user sys rssKb < <(tail -n 1 "$WORK/time")
    vals[$v.wall]+=" $wall"
    vals[$v.cpu]+=" $(awk -v u="$user" -v s="$sys" 'BEGIN { printf "%.2f", u + s }')"
    vals[$v.rss]+=" $(awk -v m="$rssKb" 'BEGIN { printf "%.0f", m / 1024 }')"
    for stage in ingest segment; do
      s=$(sed -n "s/.*\"event\":\"stage_finished\".*\"stage\":\"$stage\".*\"wall_seconds\":\([0-9.eE+-]*\).*/\1/p" "$WORK/log-$v.jsonl" | tail -1)
      [ -n "$s" ] && vals[$v.$stage]+=" $s"
    done
    # The segment stage's CPU: the process's CPU seconds between its start and end events.
    c0=$(sed -n 's/.*"cpu_seconds":\([0-9.eE+-]*\),"event":"stage_started","stage":"segment".*/\1/p' "$WORK/log-$v.jsonl" | tail -1)
    c1=$(sed -n 's/.*"cpu_seconds":\([0-9.eE+-]*\),"event":"stage_finished".*"stage":"segment".*/\1/p' "$WORK/log-$v.jsonl" | tail -1)
    [ -n "$c0" ] && [ -n "$c1" ] && vals[$v.segcpu]+=" $(awk -v a="$c0" -v b="$c1" 'BEGIN { printf "%.2f", b - a }')"
  done
done
echo "load at the end $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| run | wall s | CPU user+sys s | peak RSS MB | ingest wall s | segment wall s | segment CPU s |"
echo "|---|---|---|---|---|---|---|"
for v in "${variants[@]}"; do
  row="| $v"
  for m in wall cpu rss ingest segment segcpu; do
    # shellcheck disable=SC2086
    if [ -n "${vals[$v.$m]:-}" ]; then row+=" | $(median_min_max ${vals[$v.$m]} | awk '{ printf "%s (%s-%s)", $1, $2, $3 }')"
    else row+=" | -"; fi
  done
  echo "$row |"
done
echo "(median (min-max) of $RUNS cold runs; the mask path reads its mask in the segment stage and has no ingest; the"
echo " CT path's segmentation starts beside ingest's ct.vdb write, so its segment CPU is the process's CPU from the"
echo " segment stage's start to its end, the rest of that write included)"
echo

# The lumens: exported on the CT's field (the padded mask's study shares it).
"$FLYOVER" -q export --study "$WORK/study-ct" --lumen "$WORK/lumen-ct.nii.gz"
[ "$PADDED" != 0 ] && "$FLYOVER" -q export --study "$WORK/study-padded" --lumen "$WORK/lumen-padded.nii.gz"
python3 - "$WORK" "$PADMASK" "${variants[@]}" <<'PY'
import gzip, json, os, struct, sys
work, padmask, variants = sys.argv[1], sys.argv[2], sys.argv[3:]

def nifti_u8(path):
    d = gzip.open(path).read()
    dims = struct.unpack_from('<8h', d, 40)[1:4]
    dtype = struct.unpack_from('<h', d, 70)[0]
    if dtype != 2:
        sys.exit("mask_vs_ct: %s: expected uint8 voxels (NIfTI datatype 2), got %d" % (path, dtype))
    off = int(struct.unpack_from('<f', d, 108)[0])
    return dims, d[off:]

for v in variants:
    man = json.load(open(os.path.join(work, "study-" + v, "manifest.json")))
    seg = next(s.get("report", {}) for s in man["stages"] if s["stage"] == "segment")
    comps = seg.get("components", [])
    cuts = [c for c in seg.get("contacts", {}).get("contacts", []) if c.get("cut")]
    pieces = seg.get("pieces", [])
    print("%-7s lumen %.1f mL (mask / air kept %.1f mL); %d pieces (%d of 1 mL or more); %s; rectal tube %s; contacts cut %d" % (
        v, seg["lumen_volume_ml"], seg.get("mask_volume_ml", float("nan")), len(pieces),
        sum(1 for p in pieces if p["volume_ml"] >= 1.0),
        "air components %d kept, %d dropped" % (sum(1 for c in comps if c["kept"]), sum(1 for c in comps if not c["kept"]))
        if comps else "no air components (mask)",
        "found" if seg.get("rectal_tube", {}).get("found") else "none", len(cuts)))

lumens = {"input mask": padmask, "ct": os.path.join(work, "lumen-ct.nii.gz")}
if "padded" in variants:
    lumens["mask path (padded)"] = os.path.join(work, "lumen-padded.nii.gz")
data = {}
for name, path in lumens.items():
    dims, voxels = nifti_u8(path)
    data[name] = (dims, int.from_bytes(voxels, "little"), voxels.count(1))
names = list(data)
for i in range(len(names)):
    for j in range(i + 1, len(names)):
        (da, a, na), (db, b, nb) = data[names[i]], data[names[j]]
        if da != db:
            print("Dice %s / %s: different grids %s / %s" % (names[i], names[j], da, db))
            continue
        both = (a & b).bit_count()
        print("Dice %-18s / %-18s %.4f (voxels %d / %d, volume difference %+.2f%%)" % (
            names[i], names[j], 2.0 * both / max(1, na + nb), na, nb, 100.0 * (nb - na) / max(1, na)))
PY

if [ -f "$REF" ] && [ -x "$CLREAL" ]; then
  echo
  echo "centerline of each lumen against $REF (build/bench/centerline_real, default parameters):"
  for v in ct mask; do
    printf '  %-5s ' "$v"
    "$CLREAL" --sdf "$WORK/study-$v/lumen.vdb" --ref "$REF" | head -n 1
  done
fi
