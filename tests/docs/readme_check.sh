#!/usr/bin/env bash
# The documentation's two rules, checked:
#   1. README.md is a user's guide of at most 300 lines (the reference is in docs/);
#   2. neither the documentation (README.md, docs/**/*.md) nor a source or comment file
#      (*.cpp, *.h, *.js, *.sh, CMakeLists.txt; not .git, build folders, node_modules) names an
#      issue or a work session by number: history lives in git, the files say what and why.
# Usage: tests/docs/readme_check.sh [REPO_ROOT] [--list]
#   REPO_ROOT defaults to the checkout this script is in; --list prints every match.
# Exit 0 when both hold, else 1 with one line saying what was expected and what was seen.
set -euo pipefail

ROOT=""
LIST=0
for arg in "$@"; do
  case $arg in
    --list) LIST=1 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) ROOT=$arg ;;
  esac
done
[ -n "$ROOT" ] || ROOT=$(cd "$(dirname "$0")/../.." && pwd)
cd "$ROOT" || { echo "readme_check: expected a repository root, saw no folder '$ROOT'"; exit 1; }
[ -f README.md ] || { echo "readme_check: expected README.md in $ROOT, saw none"; exit 1; }

MAX_LINES=300
lines=$(wc -l < README.md)
if [ "$lines" -gt "$MAX_LINES" ]; then
  echo "readme_check: expected README.md to have at most $MAX_LINES lines, saw $lines"
  exit 1
fi

# What counts as naming an issue or a session by number (case-insensitive, extended regex):
# "issue 15", "issues 14", "issue #15", "session 20", "sessions 3", "the twentieth session",
# "the 20th session", "(#12)".
ORDINALS='first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth'
ORDINALS+='|thirteenth|fourteenth|fifteenth|sixteenth|seventeenth|eighteenth|nineteenth|twentieth'
ORDINALS+='|twenty-?(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth)|thirtieth|[0-9]+(st|nd|rd|th)'
PATTERN="\\bissues?[[:space:]]*(#|no\\.?)?[[:space:]]*[0-9]+"
PATTERN+="|\\bsessions?[[:space:]]*(#|no\\.?)?[[:space:]]*[0-9]+"
PATTERN+="|\\b($ORDINALS)[[:space:]-]+sessions?\\b"
PATTERN+="|\\(#[0-9]+\\)"

SELF=tests/docs/readme_check.sh
files=()
while IFS= read -r -d '' f; do
  f=${f#./}
  [ "$f" = "$SELF" ] || files+=("$f")
done < <(find . \( -type d \( -name .git -o -name node_modules -o -name 'build' -o -name 'build-*' \) -prune \) \
              -o -type f \( -name '*.cpp' -o -name '*.h' -o -name '*.js' -o -name '*.sh' -o -name CMakeLists.txt \
                            -o -path './README.md' -o -path './docs/*.md' \) -print0 | sort -z)

matches=$(grep -HnIiE "$PATTERN" "${files[@]}" || true)
if [ -n "$matches" ]; then
  count=$(printf '%s\n' "$matches" | wc -l)
  nfiles=$(printf '%s\n' "$matches" | cut -d: -f1 | sort -u | wc -l)
  first=$(printf '%s\n' "$matches" | head -3 | sed -E 's/^([^:]+:[0-9]+):.*/\1/' | paste -sd, -)
  [ "$LIST" = 1 ] && printf '%s\n' "$matches" >&2
  echo "readme_check: expected no issue or session numbers in README.md, docs/*.md or sources, saw $count in $nfiles files (first: $first; --list for all)"
  exit 1
fi
echo "readme_check: README.md $lines lines (<= $MAX_LINES), no issue or session numbers in ${#files[@]} files"
