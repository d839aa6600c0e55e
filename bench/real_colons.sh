#!/usr/bin/env bash
# Figures for real colons: per phantom variant (each difficulty
# alone, all together; CT and --truth-mask; several seeds) and on the real segmentation
# gca-colon-00020 (mask only): path mean / p95 error against the truth (mm), length ratio,
# contacts found vs truth, fly-over coverage alone and with review, review views added, and
# whether every polyp was seen by the fly-over.
#
#   bench/real_colons.sh                      (from the repository root, after a build)
#   SIZE=small SEEDS="1" VARIANTS="touching redundant" MODES=ct bench/real_colons.sh
#   SIZE=small SEEDS="4 5" VARIANTS="touching4+redundant tube+touching2" bench/real_colons.sh
#   FLYOVER=build/bin/flyover LIMIT=900 KEEP=1 GCA=0 bench/real_colons.sh
#   UNTIL=centerline SIZE=small SEEDS="4 5 6 7 8" bench/real_colons.sh   (path and contacts only)
#
# Everything happens in a fresh folder under ${TMPDIR:-/tmp} (removed at the end unless KEEP
# is set); no user study is touched. Each phantom + run is limited to LIMIT seconds (default
# 1200); a run that fails or times out gets a row saying so. Runs go --until coverage (no
# frames video); the coverage parameters are the defaults unless RENDER adds --set pairs.
#
# Definitions (the table's columns):
#   variant       "(far tube left out)" when the centerline left a narrow tube at the lumen's
#                 far end out (the terminal ileum off the cecum)
#   err mean/p95  distance (mm) from each path point to the nearest point of the truth
#                 centerline (phantoms) or of the published reference path (gca)
#   len ratio     path length / truth length (gca: / reference arc from the anus to the point
#                 of the reference nearest the path's end, as tests/volume/contacts_real_test)
#   start         distance (mm) from the path's first point to the truth's rectum end
#   along         the same, signed along the truth's direction at its start (the unit vector
#                 from its first point to its point 10 mm along): > 0 the path starts beyond
#                 the truth's start (rectum left out), < 0 short of it (towards the anus: the
#                 truth starts at the centre of the rectum's rounded end, the lumen goes on
#                 below it by about the rectum's radius)
#   contacts      truth contacts with a cut contact within 15 mm / truth contacts, then "+N"
#                 cuts that match no truth contact (gca: cuts only)
#   fly / +rev    fly-over coverage fraction of the wall, and fly-over plus review (%)
#   views         review views added
#   polyps        polyps seen by the fly-over / polyps (seen: at least half of the mesh
#                 vertices within radius + 1 mm of its centre are seen; surface_seen.ply)
set -uo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FLYOVER=$(realpath "${FLYOVER:-$ROOT/build/bin/flyover}")
SIZE=${SIZE:-medium}
SEEDS=${SEEDS:-1 2 3}
VARIANTS=${VARIANTS:-touching redundant tube spacing all}
MODES=${MODES:-ct mask}
LIMIT=${LIMIT:-1200}
GCA=${GCA:-1}
. "$ROOT/bench/shared_data.sh"
GCA_DIR=${GCA_DIR:-$(shared_data)/real/gca-colon-00020}
RENDER=${RENDER:-}
export UNTIL=${UNTIL:-coverage}
case "$UNTIL" in coverage|centerline) ;; *) echo "real_colons: UNTIL=$UNTIL: coverage or centerline" >&2; exit 1 ;; esac
[ -x "$FLYOVER" ] || { echo "real_colons: $FLYOVER: no flyover program (build first, or set FLYOVER)" >&2; exit 1; }
command -v python3 >/dev/null || { echo "real_colons: python3 is needed for the metrics" >&2; exit 1; }

WORK=$(mktemp -d "${TMPDIR:-/tmp}/flyover-real-colons.XXXXXX")
[ -n "${KEEP:-}" ] || trap 'rm -rf "$WORK"' EXIT
sets=()
for a in $RENDER; do sets+=(--set "$a"); done

# A variant is one of touching, redundant, tube, stricture, fluid, collapse, spacing, all,
# touchingN (N contacts), prone (the fluid anterior; implies fluid), ras, las, slp (the voxels
# stored in that order, the same world anatomy), noiseN (Gaussian noise of N HU; 15 by
# default, 40-80 in a low-dose CT colonography), ileum (gas in the terminal ileum, joined to
# the cecum), or several joined by "+" (e.g.
# touching4+redundant+tube, all+stricture+fluid+collapse, prone+tube+las).
flags_of() {
  local part out=""
  for part in ${1//+/ }; do
    case "$part" in
      touching) out+=" --touching 2" ;;
      touching[0-9]*) out+=" --touching ${part#touching}" ;;
      redundant) out+=" --redundant" ;;
      tube) out+=" --rectal-tube" ;;
      stricture) out+=" --stricture" ;;
      fluid) out+=" --fluid" ;;
      collapse) out+=" --collapse" ;;
      spacing) out+=" --spacing 0.8,0.8,1.25" ;;
      prone) out+=" --fluid --prone" ;;
      ras|las|slp) out+=" --orientation ${part^^}" ;;
      noise[0-9]*) out+=" --noise-hu ${part#noise}" ;;
      ileum) out+=" --ileal-reflux" ;;
      all) out+=" --touching 2 --redundant --rectal-tube --spacing 0.8,0.8,1.25" ;;
      *) echo "real_colons: unknown variant $part in $1" >&2; return 1 ;;
    esac
  done
  echo "$out"
}

# metrics KIND LABEL STUDY TRUTH SECONDS: one table row on stdout.
metrics() {
  python3 - "$@" <<'PY'
import json, math, os, struct, sys
kind, label, study, truth_path, seconds = sys.argv[1:6]

def row(cells):
    print("| " + " | ".join(cells) + " |")

def load(p):
    with open(p) as f:
        return json.load(f)

try:
    cl = load(study + "/centerline.json")
    man = load(study + "/manifest.json")
    cov = load(study + "/coverage/coverage.json") if os.environ.get("UNTIL", "coverage") == "coverage" else None
except Exception as e:  # the run failed or timed out: say so
    row([label, "run failed: " + str(e).split(":")[0]] + [""] * 10)
    sys.exit(0)
pts = cl["position_mm"]
reports = {s["stage"]: s.get("report", {}) for s in man["stages"]}
if reports.get("centerline", {}).get("far_branch_left_out"):  # a narrow tube at the far end left out
    label += " (far tube left out)"

if kind == "gca":
    ref = load(truth_path)
    truth = ref["position_mm"]
else:
    tj = load(truth_path)
    truth = tj["centerline"]["position_mm"]

# Nearest truth point per path point through a uniform grid of 10 mm cells.
CELL = 10.0
grid = {}
for i, p in enumerate(truth):
    grid.setdefault(tuple(int(math.floor(c / CELL)) for c in p), []).append(i)
def nearest(p):
    c = [int(math.floor(v / CELL)) for v in p]
    best, bi = float("inf"), -1
    for r in range(0, 40):
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                for dz in range(-r, r + 1):
                    if max(abs(dx), abs(dy), abs(dz)) != r:
                        continue
                    for i in grid.get((c[0] + dx, c[1] + dy, c[2] + dz), ()):
                        d = math.dist(p, truth[i])
                        if d < best:
                            best, bi = d, i
        if bi >= 0 and best <= r * CELL:
            break
    return best, bi
near = [nearest(p) for p in pts]
err = sorted(d for d, _ in near)
mean = sum(err) / len(err)
p95 = err[int(0.95 * (len(err) - 1))]
def length(poly):
    return sum(math.dist(poly[i], poly[i - 1]) for i in range(1, len(poly)))
plen = length(pts)
if kind == "gca":
    arc = [0.0]
    for i in range(1, len(truth)):
        arc.append(arc[-1] + math.dist(truth[i], truth[i - 1]))
    tlen = arc[near[-1][1]] - arc[near[0][1]]
else:
    tlen = length(truth)
start = math.dist(pts[0], truth[0])
# Signed start: along the truth's direction at its start (first point -> its point 10 mm on).
k, walked = 1, 0.0
while k < len(truth) - 1 and walked + math.dist(truth[k], truth[k - 1]) < 10.0:
    walked += math.dist(truth[k], truth[k - 1])
    k += 1
axis = [truth[k][i] - truth[0][i] for i in range(3)]
norm = math.sqrt(sum(a * a for a in axis)) or 1.0
along = sum((pts[0][i] - truth[0][i]) * axis[i] for i in range(3)) / norm

seg = reports.get("segment", {})
cuts = [c for c in seg.get("contacts", {}).get("contacts", []) if c.get("cut")]
if kind == "gca":
    contacts = "%d cut" % len(cuts)
else:
    tcs = tj.get("contacts", [])
    found = sum(1 for t in tcs if any(math.dist(t["position_mm"], c["position_mm"]) <= 15.0 for c in cuts))
    extra = sum(1 for c in cuts if not any(math.dist(t["position_mm"], c["position_mm"]) <= 15.0 for t in tcs))
    contacts = "%d/%d +%d" % (found, len(tcs), extra)

if cov is None:  # UNTIL=centerline: no coverage, no polyps
    row([label, "%.2f / %.2f" % (mean, p95), "%.3f" % (plen / tlen), "%.1f" % start, "%+.1f" % along, contacts]
        + ["-"] * 5 + [seconds])
    sys.exit(0)
fly = cov["flyover"]["both_cameras"]["fraction"]
wr = cov.get("flyover_with_review") or {}
rev = wr.get("fraction")
views = cov.get("review_views", 0)
unreached = wr.get("missed_regions_count", 0) if rev is not None and rev < wr.get("target", 0.995) else 0

# Polyps seen by the fly-over, from surface_seen.ply (binary: xyz float, 6 uchar per vertex).
polyps = "-"
if kind != "gca":
    with open(study + "/coverage/surface_seen.ply", "rb") as f:
        data = f.read()
    head_end = data.index(b"end_header\n") + len(b"end_header\n")
    nv = int([l for l in data[:head_end].split(b"\n") if l.startswith(b"element vertex")][0].split()[2])
    verts = [struct.unpack_from("<fffBBBBBB", data, head_end + 18 * i) for i in range(nv)]
    seen = 0
    for pol in tj.get("polyps", []):
        c, r = pol["center_mm"], pol["radius_mm"] + 1.0
        inside = [v for v in verts if abs(v[0] - c[0]) <= r and abs(v[1] - c[1]) <= r and abs(v[2] - c[2]) <= r
                  and math.dist(v[:3], c) <= r]
        if inside and 2 * sum(v[6] for v in inside) >= len(inside):
            seen += 1
    polyps = "%d/%d" % (seen, len(tj.get("polyps", [])))

row([label, "%.2f / %.2f" % (mean, p95), "%.3f" % (plen / tlen), "%.1f" % start, "%+.1f" % along, contacts,
     "%.2f" % (100 * fly), "-" if rev is None else "%.2f" % (100 * rev), str(views),
     str(unreached), polyps, seconds])
PY
}

echo "real_colons: $FLYOVER, size $SIZE, seeds $SEEDS, variants $VARIANTS, modes $MODES, limit ${LIMIT}s"
echo "machine: $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg); work folder $WORK"
echo
echo "| variant | err mean / p95 (mm) | len ratio | start (mm) | along (mm) | contacts | fly (%) | +rev (%) | views | unreached | polyps | s |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
for v in $VARIANTS; do
  vflags=$(flags_of "$v") || exit 2
  for mode in $MODES; do
    for seed in $SEEDS; do
      dir=$WORK/$v-$mode-$seed
      mkdir -p "$dir"
      label="$v $mode seed $seed"
      t0=$(date +%s)
      # shellcheck disable=SC2086
      if ! timeout "$LIMIT" "$FLYOVER" -q phantom "$dir/p.nii.gz" --truth "$dir/truth.json" --truth-mask "$dir/mask.nii.gz" \
           --size "$SIZE" --seed "$seed" $vflags > "$dir/log" 2>&1; then
        echo "| $label | phantom failed: $(tail -n 1 "$dir/log") ||||||||||| |"
        continue
      fi
      left=$((LIMIT - ($(date +%s) - t0)))
      if [ "$mode" = ct ]; then input=("$dir/p.nii.gz"); else input=(--mask "$dir/mask.nii.gz"); fi
      timeout "$((left > 1 ? left : 1))" "$FLYOVER" -q run "${input[@]}" --study "$dir/study" --until "$UNTIL" "${sets[@]}" \
        >> "$dir/log" 2>&1 || echo "  ($label: run exit $?: $(tail -n 1 "$dir/log"))" >&2
      metrics phantom "$label" "$dir/study" "$dir/truth.json" "$(($(date +%s) - t0))"
      [ -n "${KEEP:-}" ] || rm -rf "$dir"
    done
  done
done
if [ "$GCA" != 0 ]; then
  if [ -f "$GCA_DIR/large_intestine.nii.gz" ]; then
    dir=$WORK/gca
    mkdir -p "$dir"
    t0=$(date +%s)
    timeout "$LIMIT" "$FLYOVER" -q run --mask "$GCA_DIR/large_intestine.nii.gz" --study "$dir/study" --until "$UNTIL" \
      "${sets[@]}" > "$dir/log" 2>&1 || echo "  (gca: run exit $?: $(tail -n 1 "$dir/log"))" >&2
    metrics gca "gca-colon-00020 mask" "$dir/study" "$GCA_DIR/reference_path.json" "$(($(date +%s) - t0))"
  else
    echo "| gca-colon-00020 | no data at $GCA_DIR ||||||||||| |"
  fi
fi
