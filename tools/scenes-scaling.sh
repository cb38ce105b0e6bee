#!/usr/bin/env bash
# Does the number of training scenes pay? One model trained from scratch on
# the first N scenes of the generator's training part, for several N, with
# the same schedule, steps, seed and validation (the 8 `val` scenes): the
# runs differ only in how many scenes they see. docs/training.md has the
# figures ("How many scenes pay").
#
# Usage: bash tools/scenes-scaling.sh [DATA] [OUT]   (defaults /work/data/gen, /work/data/scaling)
#   COUNTS="400 100 200"   the scene counts, in this order (each a run in OUT/scenesN)
#   STEPS=15000        each run's cosine schedule
#   MODEL=wskp3        wskp3, wskp6 or afn
#   STRIDE=1           mcdenoise train --frame-stride
# Resumable: a run stopped at any point continues from its checkpoint when
# the command is run again; a finished run (its weights file there and no
# checkpoint) is skipped. The binary is copied into OUT once, so that a
# rebuild does not change the runs half-way.
# Needs the training part rendered up to the largest count:
#   TRAIN_COUNT=400 PARTS=train bash tools/render-train.sh DATA
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DATA="${1:-/work/data/gen}"
OUT="${2:-/work/data/scaling}"
COUNTS="${COUNTS:-400 100 200}"
STEPS="${STEPS:-15000}"
MODEL="${MODEL:-wskp3}"
mkdir -p "$OUT"
if [ ! -x "$OUT/mcdenoise" ]; then
    src="${MCDENOISE:-$HERE/../target/release/mcdenoise}"
    [ -x "$src" ] || (cd "$HERE/.." && cargo build --release -p mcdenoise-cli)
    cp "$src" "$OUT/mcdenoise"
fi
for n in $COUNTS; do
    run="$OUT/scenes$n"
    if [ -f "$run/$MODEL.safetensors" ] && [ ! -f "$run/$MODEL.safetensors.ckpt" ]; then
        echo "[scenes-scaling] $n scenes: done ($run/$MODEL.safetensors)"
        continue
    fi
    mkdir -p "$run/train"
    for i in $(seq 0 $((n - 1))); do
        name=$(printf 'train_%04d' "$i")
        frames=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['frames'])" "$DATA/scenes/$name.json")
        last=$(printf '%s/train/%s/ref/frame_%04d.exr' "$DATA" "$name" $((frames - 1)))
        [ -f "$last" ] || { echo "scenes-scaling: $DATA/train/$name is not rendered (no $last)" >&2; exit 1; }
        ln -sfn "$DATA/train/$name" "$run/train/$name"
    done
    echo "[scenes-scaling] $n scenes, $STEPS steps -> $run"
    MCDENOISE="$OUT/mcdenoise" MODELS="$MODEL" STEPS_WSKP3="$STEPS" STEPS_WSKP6="$STEPS" STEPS_AFN="$STEPS" \
        STRIDE="${STRIDE:-1}" TRAIN="$run/train" bash "$HERE/train-all.sh" "$DATA" "$run"
done
