#!/usr/bin/env bash
# PSNR per scene of the learned methods (and cross), for choices measured on
# the generator's held-out scenes and the foreign set (docs/quality.md).
#
#   tools/psnr_sweep.sh OUT.txt SCENE_DIR... 
#
# Each line of OUT.txt: the scene's name, then the mean PSNR dB (mcdenoise
# score against SCENE/ref) of AFN, WSKP-6 and WSKP-3, and of cross when
# CROSS=1. Environment:
#   MCDENOISE  the binary (default target/release/mcdenoise)
#   PAIR       first | mean (default first: one estimate)
#   EXTRA      more denoise flags for every method (e.g. --no-fallback)
#   CROSS=1    add a column for cross (it reads the pair whatever PAIR is)
set -euo pipefail
M=${MCDENOISE:-target/release/mcdenoise}
pair=${PAIR:-first}
out=$1
shift
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
: >"$out"
methods=("afn" "wskp --layers 6" "wskp --layers 3")
for scene in "$@"; do
    line=$(basename "$scene")
    for m in "${methods[@]}"; do
        rm -rf "$tmp/x"
        # shellcheck disable=SC2086
        "$M" denoise --method $m --pair "$pair" ${EXTRA:-} "$scene" -o "$tmp/x" >/dev/null 2>"$tmp/err" || { cat "$tmp/err" >&2; exit 1; }
        line="$line $("$M" score -r "$scene/ref" "$tmp/x" | tail -1 | awk '{print $3}')"
    done
    if [ "${CROSS:-0}" = 1 ]; then
        rm -rf "$tmp/x"
        # shellcheck disable=SC2086
        "$M" denoise --method cross ${EXTRA:-} "$scene" -o "$tmp/x" >/dev/null 2>"$tmp/err" || { cat "$tmp/err" >&2; exit 1; }
        line="$line $("$M" score -r "$scene/ref" "$tmp/x" | tail -1 | awk '{print $3}')"
    fi
    echo "$line" | tee -a "$out"
done
