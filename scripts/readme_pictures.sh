#!/usr/bin/env bash
# The README's pictures, made by the project's own commands: the main job's tension figure and its
# 3-D page, screenshotted by Debian's chromium (headless) at t = 6.2 s, when the squeezed prism rattles.
#   bash scripts/readme_pictures.sh      (from the repository; needs chromium: apt-get install chromium)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
tensegrity-sim run --quiet --plot --view > summary.txt
cat summary.txt
stem="$(basename "$(awk '$1 == "log" {print $2}' summary.txt)" .mcap)"
cp "plots/$stem/tensions.png" "$repo/docs/images/main_job_tensions.png"
chromium --headless --no-sandbox --disable-gpu --disable-background-networking --disable-component-update \
    --disable-sync --no-first-run --user-data-dir="$work/profile" --window-size=1000,700 \
    --virtual-time-budget=15000 --screenshot="$repo/docs/images/main_job_view.png" \
    "file://$work/plots/$stem.html#t=6.2" 2>/dev/null
echo "wrote docs/images/main_job_tensions.png and docs/images/main_job_view.png"
