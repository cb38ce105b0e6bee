#!/usr/bin/env bash
# The blotch band's error split into noise and bias (tools/blotch_split.py):
# the frames of a scene rendered N times with other seeds, each denoised by
# the methods and by Intel Open Image Denoise, against the references of a
# sequence already rendered from the same scene file (same camera, size and
# spp). Resumable: renders and outputs that exist are kept.
#
# Usage: bash tools/blotch-split.sh SCENE.json REF_SEQ OUT [render.py args]
#   e.g. bash tools/blotch-split.sh tools/scenes/foreign/lounge_pan.json \
#            /work/data/foreign/lounge_pan /work/data/split/lounge_pan --frames 1
#        bash tools/blotch-split.sh tools/scenes/foreign/cornell.json \
#            /work/data/foreign/cornell_1spp /work/data/split/cornell_1spp --frames 1 --spp 1
#   N=16                 realisations (seeds SEED0+1 .. SEED0+N)
#   SEED0=9000
#   METHODS="wskp6 afn"  of wskp3, wskp6, afn, ta, atrous, sure-atrous
#   EXTRA="" TAG=""      more `mcdenoise denoise` arguments for every method,
#                        and a suffix for their labels (e.g. EXTRA=--no-wide-pass TAG=nw)
#   OIDN=high            OIDN's quality beside them (empty: none; needs
#                        bash tools/setup-peers.sh PEERS=oidn)
#   FRAMES=0,-1          the frames scored (python indices)
#   BIN=target/release/mcdenoise
# Every method reads one estimate (`--pair first`), as OIDN does. Cost on a
# 2-core machine: a 256x144 frame renders in about 1 s (no reference) and
# denoises in 50 ms; N = 16 of an 8-frame sequence is a few minutes.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
[ $# -ge 3 ] || { sed -n '2,25p' "$0" >&2; exit 2; }
SCENE=$1; REF=$2; OUT=$3; shift 3
N="${N:-16}"; SEED0="${SEED0:-9000}"; METHODS="${METHODS:-wskp6 afn}"; OIDN="${OIDN-high}"; EXTRA="${EXTRA:-}"
BIN="${BIN:-$HERE/../target/release/mcdenoise}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
[ -f "$SCENE" ] || { echo "blotch-split.sh: no scene file $SCENE" >&2; exit 1; }
[ -d "$REF/ref" ] || { echo "blotch-split.sh: $REF has no ref/ frames" >&2; exit 1; }
[ -x "$BIN" ] || { echo "blotch-split.sh: no $BIN (cargo build --release -p mcdenoise-cli)" >&2; exit 1; }
# shellcheck disable=SC1091
[ -f "$HERE/render.env" ] && source "$HERE/render.env"
labels=()
for m in $METHODS; do
    case $m in
        wskp3) args=(--method wskp --layers 3) ;;
        wskp6) args=(--method wskp --layers 6) ;;
        afn | ta | atrous | sure-atrous) args=(--method "$m") ;;
        *) echo "blotch-split.sh: unknown method $m" >&2; exit 2 ;;
    esac
    labels+=("$m${TAG:+-$TAG}")
done
[ -n "$OIDN" ] && labels+=("oidn-$OIDN")
for k in $(seq 1 "$N"); do
    real="$OUT/real/s$k"
    "$PY" "$HERE/render.py" "$SCENE" --out "$real" --no-ref --resume --seed $((SEED0 + k)) "$@" | grep -v '^frame ' || true
    i=0
    for m in $METHODS; do
        case $m in
            wskp3) args=(--method wskp --layers 3) ;;
            wskp6) args=(--method wskp --layers 6) ;;
            *) args=(--method "$m") ;;
        esac
        dst="$OUT/${labels[$i]}_$k"
        # shellcheck disable=SC2086
        if [ ! -d "$dst" ]; then
            rm -rf "$dst.part"
            "$BIN" denoise "${args[@]}" --pair first $EXTRA "$real" -o "$dst.part" >/dev/null 2>>"$OUT/denoise.log" && mv "$dst.part" "$dst"
        fi
        i=$((i + 1))
    done
    if [ -n "$OIDN" ]; then
        dst="$OUT/oidn-${OIDN}_$k"
        if [ ! -d "$dst" ]; then
            rm -rf "$dst.part"
            "$HERE/.venv-peers/bin/python" "$HERE/oidn_denoise.py" "$real" -o "$dst.part" --quality "$OIDN" >/dev/null \
                && mv "$dst.part" "$dst"
        fi
    fi
done
"$PY" "$HERE/blotch_split.py" "$REF" "$OUT" "${labels[@]}" --frames "${FRAMES:-0,-1}"
