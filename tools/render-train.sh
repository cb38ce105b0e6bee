#!/usr/bin/env bash
# Renders the generated training data of the learned denoisers: scene files
# from tools/gen_scenes.py (deterministic from the seed), each rendered by
# tools/render.py. Resumable: a finished sequence is skipped, an unfinished
# one continues at its first missing frame; stop it at any time and run the
# same command again.
#
# Usage: bash tools/render-train.sh [DEST]          (default /work/data/gen)
#   PARTS="train val test"   which parts (default all three, in that order)
#   TRAIN_COUNT=400 VAL_COUNT=8 TEST_COUNT=8   scenes per part
#   SEED=1                   the generator's seed
#   NICE=19                  niceness of the renders
#
# Layout: DEST/scenes/{train,val,test}_NNNN.json (+ assets/), and
# DEST/{train,val,test}/{train,val,test}_NNNN/frame_NNNN.exr with ref/;
# DEST/manifest.json (tools/data_manifest.py) lists them when it finishes.
#   train: 400 scenes x 8 frames, 192x144, inputs at 1-16 spp (half the
#          scenes 1 spp), 128-spp targets (unbiased and noisy: the training
#          loss is one whose minimiser a noisy target does not move), half
#          the scenes with Mitsuba's raw albedo AOV
#   val:   8 scenes x 8 frames, 192x144, 512-spp references
#   test:  8 scenes x 16 frames, 256x144, 1024-spp references (held-out
#          scenes of the generator; never trained or validated on)
#   hi:    64 scenes x 4 frames, 192x144, inputs at 16, 32 or 64 spp (the
#          AOVs at as many), 512-spp targets: real low-noise inputs, not
#          only the emulated ones (not in the default PARTS; HI_COUNT)
# Render budget (2-core Zen 4, idle): about 1.3 s a training frame (3200
# frames: 70 min), 4 s a validation frame, 15 s a test frame (30 min).
# Needs: bash tools/setup-render.sh once.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DEST="${1:-/work/data/gen}"
PARTS="${PARTS:-train val test}"
SEED="${SEED:-1}"
NICE="${NICE:-19}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
# shellcheck disable=SC1091
[ -f "$HERE/render.env" ] && source "$HERE/render.env"

for part in $PARTS; do
    case $part in
        train) args=(--count "${TRAIN_COUNT:-400}" --frames 8 --ref-spp 128 --width 192 --height 144) ;;
        val) args=(--count "${VAL_COUNT:-8}" --frames 8 --ref-spp 512 --width 192 --height 144) ;;
        test) args=(--count "${TEST_COUNT:-8}" --frames 16 --ref-spp 1024 --width 256 --height 144) ;;
        hi) args=(--count "${HI_COUNT:-64}" --frames 4 --ref-spp 512 --width 192 --height 144 --spp 16,32,64) ;;
        *) echo "unknown part $part" >&2; exit 2 ;;
    esac
    "$PY" "$HERE/gen_scenes.py" --out "$DEST/scenes" --split "$part" --seed "$SEED" "${args[@]}"
    ref_dtype=half
    [ "$part" = test ] && ref_dtype=float
    for json in "$DEST/scenes/${part}"_*.json; do
        name=$(basename "$json" .json)
        out="$DEST/$part/$name"
        frames=$("$PY" -c "import json,sys; print(json.load(open(sys.argv[1]))['frames'])" "$json")
        if [ -f "$(printf '%s/ref/frame_%04d.exr' "$out" $((frames - 1)))" ]; then
            continue
        fi
        echo "[render-train] $part/$name"
        nice -n "$NICE" "$PY" "$HERE/render.py" "$json" --out "$out" --resume --ref-dtype "$ref_dtype" \
            | grep -v '^frame ' || { echo "[render-train] $part/$name failed" | tee -a "$DEST/failed.txt" >&2; }
    done
done
# DEST/manifest.json: every sequence, its settings and the coverage totals.
python3 "$HERE/data_manifest.py" "$DEST" --print
if [ -s "$DEST/failed.txt" ]; then
    echo "[render-train] some sequences failed (listed in $DEST/failed.txt)" >&2
    exit 1
fi
echo "[render-train] done: $DEST"
