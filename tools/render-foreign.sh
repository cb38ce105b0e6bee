#!/usr/bin/env bash
# Renders the foreign test set: scenes the training generator does not make
# (hand-written scene files in tools/scenes/foreign/, meshes it never uses,
# Mitsuba's raw albedo AOV) and Mitsuba's built-in Cornell box at 1, 4, 16
# and 64 spp. Never trained, validated or tuned on. Resumable (an unfinished
# sequence continues at its first missing frame).
#
# Usage: bash tools/render-foreign.sh [DEST]     (default /work/data/foreign)
# Layout: DEST/{lounge_pan,lounge_light,gallery_orbit,corridor}/frame_NNNN.exr
# with ref/ (256x144, 1 spp, 16-24 frames, 1024-spp references), and
# DEST/cornell_{1,4,16,64}spp/ (256x256, 2 frames, one shared 4096-spp
# reference). About 30 minutes of the 2-core machine.
# Needs: bash tools/setup-render.sh once.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DEST="${1:-/work/data/foreign}"
NICE="${NICE:-19}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
# shellcheck disable=SC1091
[ -f "$HERE/render.env" ] && source "$HERE/render.env"
S="$HERE/scenes/foreign"
"$PY" "$S/meshes.py"
r() { nice -n "$NICE" "$PY" "$HERE/render.py" "$@" --resume --ref-dtype float | grep -v '^frame '; }
for s in lounge_pan lounge_light gallery_orbit corridor; do
    r "$S/$s.json" --out "$DEST/$s"
done
# The Cornell box at 1, 4, 16 and 64 spp shares one reference (it does not
# depend on --spp): rendered once, with the 1-spp frames, and linked.
r "$S/cornell.json" --out "$DEST/cornell_1spp" --spp 1
for spp in 4 16 64; do
    r "$S/cornell.json" --out "$DEST/cornell_${spp}spp" --spp "$spp" --no-ref
    rm -rf "$DEST/cornell_${spp}spp/ref"
    cp -r "$DEST/cornell_1spp/ref" "$DEST/cornell_${spp}spp/ref"
done
echo "[render-foreign] done: $DEST"
