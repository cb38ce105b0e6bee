#!/usr/bin/env bash
# The blotch band's error split into noise and bias (tools/blotch_split.py):
# the frames of a scene rendered N times with other seeds, each denoised by
# the methods and by Intel Open Image Denoise, against the references of a
# sequence already rendered from the same scene file (same camera, size and
# spp). Resumable: renders and outputs that exist are kept.
#
# Usage: bash tools/blotch-split.sh SCENE.json REF_SEQ OUT [render.py args]
#   e.g. bash tools/blotch-split.sh tools/scenes/foreign/lounge_pan.json \
#            /work/data/foreign/lounge_pan /work/data/split/lounge_pan --frame-range 0:1
#        bash tools/blotch-split.sh tools/scenes/foreign/cornell.json \
#            /work/data/foreign/cornell_1spp /work/data/split/cornell_1spp --frame-range 0:1 --spp 1
#   The render arguments must render REF_SEQ's frames: its spp and size,
#   and --frame-range A:B for some of its frames (not --frames, which
#   spreads the camera path over fewer frames). OUT keeps them (OUT/real/args)
#   and refuses others.
#   N=16                 realisations (seeds SEED0+1 .. SEED0+N)
#   SEED0=9000
#   METHODS="wskp6 afn"  of wskp3, wskp6, afn, ta, atrous, sure-atrous
#   EXTRA="" TAG=""      more `mcdenoise denoise` arguments for every method,
#                        and the suffix of their labels, which EXTRA needs
#                        (e.g. EXTRA=--no-wide-pass TAG=nw)
#   OIDN=high            OIDN's quality beside them (empty: none; needs
#                        bash tools/setup-peers.sh PEERS=oidn)
#   FRAMES=0,-1          the frames scored (indices into the rendered ones)
#   BIN=target/release/mcdenoise
# Every method reads one estimate (`--pair first`), as OIDN does. Cost on a
# 2-core machine: a 256x144 frame renders in about 1 s (no reference) and
# denoises in 50 ms; N = 16 of an 8-frame sequence is a few minutes. A
# failed render or denoise stops the script (its log: OUT/render.log,
# OUT/denoise.log); run it again to go on.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
[ $# -ge 3 ] || { sed -n '2,/^set -euo/p' "$0" | grep '^#' >&2; exit 2; }
SCENE=$1; REF=$2; OUT=$3; shift 3
N="${N:-16}"; SEED0="${SEED0:-9000}"; METHODS="${METHODS:-wskp6 afn}"; OIDN="${OIDN-high}"; EXTRA="${EXTRA:-}"
BIN="${BIN:-$HERE/../target/release/mcdenoise}"
PY="$HERE/.venv/bin/python"
[ -x "$PY" ] || { echo "run bash tools/setup-render.sh first" >&2; exit 1; }
[ -f "$SCENE" ] || { echo "blotch-split.sh: no scene file $SCENE" >&2; exit 1; }
[ -d "$REF/ref" ] || { echo "blotch-split.sh: $REF has no ref/ frames" >&2; exit 1; }
[ -x "$BIN" ] || { echo "blotch-split.sh: no $BIN (cargo build --release -p mcdenoise-cli)" >&2; exit 1; }
[ -n "$EXTRA" ] && [ -z "${TAG:-}" ] && { echo "blotch-split.sh: EXTRA needs a TAG for its labels" >&2; exit 2; }
mkdir -p "$OUT/real"
args_now="$(basename "$SCENE") $*"
if [ -f "$OUT/real/args" ]; then
    [ "$(cat "$OUT/real/args")" = "$args_now" ] \
        || { echo "blotch-split.sh: $OUT was rendered with '$(cat "$OUT/real/args")', not '$args_now'" >&2; exit 2; }
else
    echo "$args_now" > "$OUT/real/args"
fi
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
    "$PY" "$HERE/render.py" "$SCENE" --out "$real" --no-ref --resume --seed $((SEED0 + k)) "$@" >>"$OUT/render.log" 2>&1 \
        || { echo "blotch-split.sh: the render of seed $((SEED0 + k)) failed (see $OUT/render.log)" >&2; exit 1; }
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
            "$BIN" denoise "${args[@]}" --pair first $EXTRA "$real" -o "$dst.part" >/dev/null 2>>"$OUT/denoise.log" \
                || { echo "blotch-split.sh: $m on $real failed (see $OUT/denoise.log)" >&2; exit 1; }
            mv "$dst.part" "$dst"
        fi
        i=$((i + 1))
    done
    if [ -n "$OIDN" ]; then
        dst="$OUT/oidn-${OIDN}_$k"
        if [ ! -d "$dst" ]; then
            rm -rf "$dst.part"
            "$HERE/.venv-peers/bin/python" "$HERE/oidn_denoise.py" "$real" -o "$dst.part" --quality "$OIDN" \
                >/dev/null 2>>"$OUT/denoise.log" \
                || { echo "blotch-split.sh: OIDN on $real failed (see $OUT/denoise.log)" >&2; exit 1; }
            mv "$dst.part" "$dst"
        fi
    fi
done
"$PY" "$HERE/blotch_split.py" "$REF" "$OUT" "${labels[@]}" --frames "${FRAMES:-0,-1}"
