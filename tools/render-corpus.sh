#!/usr/bin/env bash
# Renders the test corpus of tests/fixtures/corpus (scenes:
# tools/scenes/corpus/*.json, written by tools/make_scenes.py): small frames
# with the second estimate B.* and high-spp references, checked in. The tests
# (tests/tests/corpus.rs) use every frame as A+B and, with B.* dropped, as a
# single estimate.
#
# Usage: bash tools/render-corpus.sh [DEST]   (default tests/fixtures/corpus)
# Layout: DEST/{cornell,box}_{4,16,64}spp/frame_0000.exr and DEST/{cornell,box}_ref/,
# DEST/{glossy,hdr,dim,metals}/frame_*.exr with their ref/. About 25 minutes of a
# 2-core machine (the references).
# Needs: bash tools/setup-render.sh once.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DEST="${1:-$HERE/../tests/fixtures/corpus}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
# shellcheck disable=SC1091
[ -f "$HERE/render.env" ] && source "$HERE/render.env"
S="$HERE/scenes/corpus"
r() { nice -n 10 "$PY" "$HERE/render.py" "$@" --dtype half --ref-dtype half; }
mkdir -p "$DEST"
# The Cornell boxes at 4, 16 and 64 spp share one reference (it does not
# depend on --spp): a 1-spp render whose noisy frame is dropped.
for box in cornell box; do
    for spp in 4 16 64; do
        r "$S/corpus_$box.json" --out "$DEST/${box}_${spp}spp" --spp "$spp" --no-ref
    done
    r "$S/corpus_$box.json" --out "$DEST/.${box}_tmp" --spp 1
    rm -rf "${DEST:?}/${box}_ref"
    mv "$DEST/.${box}_tmp/ref" "$DEST/${box}_ref"
    rm -rf "${DEST:?}/.${box}_tmp"
done
r "$S/corpus_glossy.json" --out "$DEST/glossy"
# Mitsuba's own albedo AOV: above 1 (up to ~10) on the rough metals.
r "$S/corpus_hdr.json" --out "$DEST/hdr" --albedo mitsuba
r "$S/corpus_dim.json" --out "$DEST/dim"
# Mitsuba's raw albedo AOV (the scene file says so): metals, glass, black paint.
r "$S/corpus_metals.json" --out "$DEST/metals"
du -sh "$DEST"
