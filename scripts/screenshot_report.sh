#!/usr/bin/env bash
# Screenshot a seedmap report.html with headless Chromium (to check that it renders offline).
#
# Usage: scripts/screenshot_report.sh RESULT_DIR/report.html [OUT.png] [WIDTH] [HEIGHT]
#   OUT.png defaults to report.png next to the report; the page is rendered at WIDTHxHEIGHT
#   (default 1200x3000, tall enough for the metrics table, plots and the 3D view).
# Needs chromium, chromium-browser or google-chrome on PATH (Debian: apt-get install -y chromium).
# The report is self-contained (plotly.js inlined), so no network access is needed.
set -euo pipefail

if [[ $# -lt 1 || ! -f "$1" ]]; then
  echo "usage: $0 REPORT.html [OUT.png] [WIDTH] [HEIGHT]" >&2
  exit 2
fi
report="$(realpath "$1")"
out="${2:-$(dirname "$report")/report.png}"
width="${3:-1200}"
height="${4:-3000}"

browser=""
for b in chromium chromium-browser google-chrome; do
  if command -v "$b" >/dev/null 2>&1; then browser="$b"; break; fi
done
if [[ -z "$browser" ]]; then
  echo "error: no headless browser found (install chromium: apt-get install -y chromium)" >&2
  exit 2
fi

profile="$(mktemp -d)"
trap 'rm -rf "$profile"' EXIT
# --virtual-time-budget lets plotly finish drawing the WebGL 3D view before the shot is taken
"$browser" --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader \
  --hide-scrollbars --user-data-dir="$profile" --window-size="${width},${height}" \
  --virtual-time-budget=15000 --screenshot="$(realpath -m "$out")" "file://${report}" >/dev/null 2>&1
if [[ ! -s "$out" ]]; then
  echo "error: $browser wrote no screenshot for $report" >&2
  exit 1
fi
echo "wrote $out"
