#!/usr/bin/env bash
# Trains the bundled weights of the learned methods (std-host/weights/) on
# the generated data of tools/render-train.sh. Resumable: each model
# checkpoints every 5 minutes (OUT/MODEL.safetensors.ckpt) and a second run
# of the same command continues from the checkpoint (with whatever data is
# there by then); a finished model's checkpoint is removed, so running the
# command again trains it anew. docs/training.md has the figures of the
# bundled weights.
#
# Usage: bash tools/train-all.sh [DATA] [OUT]   (defaults /work/data/gen, std-host/weights)
#   MODELS="wskp3 afn wskp6"   which models, in this order (default)
#   STEPS_WSKP3=60000 STEPS_WSKP6=40000 STEPS_AFN=30000   the cosine schedule's length
#   THREADS=2
#   CLIP=0.5                   the gradient-norm clip (0: off; see docs/training.md)
#   LOSS=l1-log                the loss (mcdenoise train --loss)
#   BAND=0                     the band term's weight beside it (mcdenoise train --band-weight)
#   FIRST=0                    the share of crops from first frames, without history
#                              (mcdenoise train --first-frames)
#   STRIDE=1                   one frame in STRIDE of each sequence made a sample (mcdenoise
#                              train --frame-stride): 2 fits twice the scenes in memory
#   TA_CLAMP=1                 the accumulation's history clamp (mcdenoise train --ta-clamp; 0: off,
#                              as the weights of before it: resume their checkpoints with 0)
#   TRAIN=DIR VAL=DIR          other training / validation directories (default DATA/train, DATA/val)
#   INIT=DIR                   fine-tune: start each model from DIR/MODEL.safetensors (a new cosine
#                              schedule from step 0; a checkpoint in OUT still resumes first)
#   LR=1e-3                    Adam's peak learning rate (a fine-tune: lower, e.g. 3e-4)
#   also: afn-ta-only, afn-1spp-only (AFN's ablation, 5000 steps each)
# The training data is DATA/train (every complete sequence), the validation
# DATA/val; DATA/test is never read here.
# Time on the 2-core Zen 4 machine, idle: WSKP-3 26 steps/s (60k: 40 min),
# WSKP-6 15 steps/s (40k: 45 min), AFN 8.5 steps/s (30k: 60 min).
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
DATA="${1:-/work/data/gen}"
OUT="${2:-$HERE/../std-host/weights}"
MODELS="${MODELS:-wskp3 afn wskp6}"
THREADS="${THREADS:-2}"
BIN="${MCDENOISE:-$HERE/../target/release/mcdenoise}"
[ -x "$BIN" ] || (cd "$HERE/.." && cargo build --release)
TRAIN="${TRAIN:-$DATA/train}"
VAL="${VAL:-$DATA/val}"
[ -d "$TRAIN" ] || { echo "no $TRAIN: run bash tools/render-train.sh $DATA first" >&2; exit 1; }
mkdir -p "$OUT"
common=(--data "$TRAIN" --val "$VAL" --batch 8 --crop 128 --threads "$THREADS" --seed 1
    --checkpoint-minutes 5 --lr-schedule cosine --lr "${LR:-1e-3}" --clip "${CLIP:-0.5}" --loss "${LOSS:-l1-log}" --band-weight "${BAND:-0}"
    --first-frames "${FIRST:-0}" --frame-stride "${STRIDE:-1}"
    --ta-clamp "${TA_CLAMP:-1}")
for m in $MODELS; do
    case "$m" in
        wskp3) args=(--method wskp --layers 3 --steps "${STEPS_WSKP3:-60000}" --val-every 5000) ;;
        wskp6) args=(--method wskp --layers 6 --steps "${STEPS_WSKP6:-40000}" --val-every 5000) ;;
        afn) args=(--method afn --steps "${STEPS_AFN:-30000}" --val-every 2500) ;;
        afn-ta-only) args=(--method afn --variant ta-only --steps 5000 --val-every 2500) ;;
        afn-1spp-only) args=(--method afn --variant 1spp-only --steps 5000 --val-every 2500) ;;
        *) echo "unknown model $m" >&2; exit 2 ;;
    esac
    w="$OUT/$m.safetensors"
    resume=()
    [ -f "$w.ckpt" ] && resume=(--resume "$w.ckpt")
    [ -n "${INIT:-}" ] && [ -f "$INIT/$m.safetensors" ] && resume+=(--init "$INIT/$m.safetensors")
    echo "[train-all] $m: ${args[*]} ${resume[*]}"
    "$BIN" train "${common[@]}" "${args[@]}" "${resume[@]}" --log "$OUT/$m.log.csv" -o "$w" 2>&1 | tee "$OUT/$m.train.txt"
    rm -f "$w.ckpt"
done
