#!/usr/bin/env bash
# CTest fixture of the browser test: installs playwright-core (pinned by package-lock.json) into
# node_modules here with `npm ci`, only when it is missing or older than the lock file, so the
# test runs offline once installed. Nothing to do without chromium (the test then skips).
set -euo pipefail
dir=$1
chromium=${FLYOVER_CHROMIUM:-}
if [ -z "$chromium" ]; then
  for c in /usr/bin/chromium /usr/bin/chromium-browser; do [ -x "$c" ] && chromium=$c && break; done
fi
if [ -z "$chromium" ]; then
  echo "npm_ci.sh: no chromium: the browser test will skip; playwright-core not installed"
  exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
  echo "npm_ci.sh: npm not found: run scripts/setup.sh (installs nodejs and npm)" >&2
  exit 1
fi
stamp="$dir/node_modules/.package-lock.json"
if [ -f "$dir/node_modules/playwright-core/package.json" ] && [ -f "$stamp" ] && [ ! "$dir/package-lock.json" -nt "$stamp" ]; then
  echo "npm_ci.sh: node_modules up to date"
  exit 0
fi
cd "$dir"
npm ci --no-audit --no-fund --loglevel=error
echo "npm_ci.sh: playwright-core installed in $dir/node_modules"
