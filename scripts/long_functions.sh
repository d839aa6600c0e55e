#!/usr/bin/env bash
# Lists the functions over MAX_FUNCTION lines (default 150) and the files over MAX_FILE lines
# (default 900) in the non-test C++ sources (style.md: a sign to split).
#   scripts/long_functions.sh [--check] [ROOT]
# A function is counted from its opening brace alone on a line in column 0 to the closing brace
# in column 0 (the layout clang-format gives this tree); lambdas and local classes count toward
# the function around them. --check: exit 1 when a file is over MAX_FILE lines, except those
# listed in scripts/long_files_allowed.txt, if it exists (each with why it is still long).
set -euo pipefail
check=0
[ "${1:-}" = --check ] && { check=1; shift; }
ROOT=${1:-$(cd "$(dirname "$0")/.." && pwd)}
MAX_FUNCTION=${MAX_FUNCTION:-150}
MAX_FILE=${MAX_FILE:-900}
cd "$ROOT"
mapfile -t files < <(git ls-files --cached --others --exclude-standard 2>/dev/null -- '*.cpp' '*.h' '*.inc' | grep -v -e '^tests/' -e '^build' || true)
[ ${#files[@]} -gt 0 ] || mapfile -t files < <(find . -path ./build -prune -o -path ./tests -prune -o \( -name '*.cpp' -o -name '*.h' -o -name '*.inc' \) -print | sed 's|^\./||')

echo "functions over $MAX_FUNCTION lines:"
awk -v max="$MAX_FUNCTION" '
    FNR == 1 { start = 0; prev = "" }
    /^\{[[:space:]]*$/ { start = FNR; sig = prev }
    /^\}/ { if (start) { n = FNR - start + 1; if (n > max) printf "  %5d  %s:%d  %s\n", n, FILENAME, start, sig; start = 0 } }
    $0 !~ /^[[:space:]]*$/ { prev = $0 }
' "${files[@]}" | sort -rn

echo "files over $MAX_FILE lines:"
allowed=scripts/long_files_allowed.txt
status=0
while read -r n f; do
    [ "$f" = total ] && continue
    [ "$n" -gt "$MAX_FILE" ] || continue
    if [ -f "$allowed" ] && grep -q "^$f\b" "$allowed"; then
        echo "  $n  $f  (allowed for now: $allowed)"
    else
        echo "  $n  $f"
        status=1
    fi
done < <(wc -l "${files[@]}" | sort -rn)
[ $check = 1 ] || status=0
exit $status
