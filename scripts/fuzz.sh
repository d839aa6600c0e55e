#!/usr/bin/env bash
# Builds and runs the libFuzzer target for the scan header readers (tests/fuzz/).
# Usage: scripts/fuzz.sh [SECONDS]   (default 300; 0 = build only)
# Needs clang and libclang-rt-14-dev (libFuzzer) from Debian: installed here when missing
# (as root or with password-less sudo), not by scripts/setup.sh, since the main build and
# CI do not fuzz. Builds in $BUILD_DIR (default build-fuzz); crashes land in $BUILD_DIR/crashes.
set -euo pipefail
cd "$(dirname "$0")/.."
RUN_SECONDS=${1:-300}
BUILD_DIR=${BUILD_DIR:-build-fuzz}

missing=()
for p in clang libclang-rt-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo -n"
  echo "fuzz.sh: installing ${missing[*]}"
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

CC=clang CXX=clang++ cmake -S tests/fuzz -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$BUILD_DIR"
[ "$RUN_SECONDS" -eq 0 ] && exit 0

# Seed corpus: every small fixture, prefixed with the byte that selects its extension.
corpus="$BUILD_DIR/corpus"; mkdir -p "$corpus" "$BUILD_DIR/crashes"
seed() { { printf "\\x$(printf %02x "$1")"; cat "$2"; } > "$corpus/seed-$1-$(basename "$2")"; }
for f in $(find data/fixtures -type f -size -64k); do
  case "$f" in
    *.nii.gz) seed 1 "$f" ;; *.nii) seed 0 "$f" ;; *.nrrd) seed 2 "$f" ;; *.nhdr) seed 3 "$f" ;;
    *.mha) seed 4 "$f" ;; *.mhd) seed 5 "$f" ;; */dicom/*) seed 6 "$f"; seed 7 "$f" ;;
  esac
done
# ASan: ITK's and GDCM's own huge allocations from absurd headers are reported as errors
# (not crashes) only if the allocator may return null; keep that explicit.
ASAN_OPTIONS=${ASAN_OPTIONS:-allocator_may_return_null=1:detect_leaks=0} \
  "$BUILD_DIR/fuzz_image_header" "$corpus" -max_total_time="$RUN_SECONDS" -max_len=65536 -timeout=30 \
  -rss_limit_mb=4096 -artifact_prefix="$BUILD_DIR/crashes/" -print_final_stats=1
