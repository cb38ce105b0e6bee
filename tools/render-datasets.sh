#!/usr/bin/env bash
# Renders the training, validation and held-out test sequences of the
# learned denoisers (scenes: tools/scenes/data/*.json, written by
# tools/make_scenes.py) with tools/render.py. The data is not in the
# repository (about 0.1 GB); this script remakes it, skipping a sequence
# whose last reference frame already exists.
#
# Usage: bash tools/render-datasets.sh [DEST]   (default /work/data)
#        PARTS="train val test" to choose parts.
#        TRAIN_REF_SPP=N (train and val) and TEST_REF_SPP=N, TEST_FRAMES=N
#        (held-out) override the scene files' reference samples and frame
#        counts, to fit a render budget; the values used are in each
#        sequence's render_info.json.
# Needs: bash tools/setup-render.sh once.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DEST="${1:-/work/data}"
PARTS="${PARTS:-train val test}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
# shellcheck disable=SC1091
[ -f "$HERE/render.env" ] && source "$HERE/render.env"

render() { # part scene
    local part=$1 scene=$2
    local json="$HERE/scenes/data/$scene.json"
    local out="$DEST/$part/$scene"
    local frames extra=()
    frames=$("$PY" -c "import json,sys; print(json.load(open(sys.argv[1]))['frames'])" "$json")
    if [ "$part" = test ]; then
        [ -n "${TEST_FRAMES:-}" ] && frames=$TEST_FRAMES && extra+=(--frames "$TEST_FRAMES")
        [ -n "${TEST_REF_SPP:-}" ] && extra+=(--ref-spp "$TEST_REF_SPP")
    elif [ -n "${TRAIN_REF_SPP:-}" ]; then
        extra+=(--ref-spp "$TRAIN_REF_SPP")
    fi
    local last
    last=$(printf '%s/ref/frame_%04d.exr' "$out" $((frames - 1)))
    if [ -f "$last" ]; then
        echo "[render-datasets] $part/$scene: done already"
        return
    fi
    echo "[render-datasets] $part/$scene: $frames frames"
    nice -n 10 "$PY" "$HERE/render.py" "$json" --out "$out" --ref-dtype float "${extra[@]}"
}

for part in $PARTS; do
    for json in "$HERE"/scenes/data/"$part"_*.json "$HERE"/scenes/data/heldout_*.json; do
        scene=$(basename "$json" .json)
        case "$part:$scene" in
            train:train_*|val:val_*|test:heldout_*) render "$part" "$scene" ;;
        esac
    done
done
echo "[render-datasets] all parts in $DEST"
