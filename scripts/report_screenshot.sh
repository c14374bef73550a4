#!/usr/bin/env bash
# The README's report screenshot: the demo's report.html rendered by headless Chromium.
# Usage: scripts/report_screenshot.sh [OUT.png]   (BIN=path to a release tessera)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${1:-$HERE/report-demo.png}
BIN=${BIN:-$HERE/../target/release/tessera}
W=$(mktemp -d /tmp/tessera-shot.XXXXXX)
trap 'rm -rf "$W"' EXIT
"$BIN" -q demo --out "$W/demo"
chromium --headless --no-sandbox --disable-gpu --hide-scrollbars --no-first-run \
  --user-data-dir="$W/profile" --window-size=1200,1250 --screenshot="$OUT" \
  "file://$W/demo/tiles/report.html" 2> /dev/null
echo "$OUT"
