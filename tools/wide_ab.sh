#!/usr/bin/env bash
# The wide pass on and off (docs/quality.md, "The wide pass"): for each
# sequence, PSNR dB (relMSE), mean over the frames, of WSKP-3, WSKP-6 and
# AFN with one estimate (--pair first) and with the pair's mean, each with
# the pass (the default) and without (--no-wide-pass); then the blotch
# figures (tools/blotch.py, 5x5-17x17 band) of frame 0 and the last frame,
# one estimate, beside OIDN high on the same frames.
#
#   bash tools/wide_ab.sh OUT_DIR SEQ_DIR...
#
# OUT_DIR keeps the outputs (OUT_DIR/{on,off}/SEQ/{wskp3,wskp6,afn},
# OUT_DIR/oidn/SEQ). Needs target/release/mcdenoise (or $MCDENOISE) and
# tools/.venv-peers (tools/setup-peers.sh; PEERS=oidn is enough).
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
M=${MCDENOISE:-$HERE/../target/release/mcdenoise}
PY="$HERE/.venv-peers/bin/python"
out=$1
shift
declare -A flags=([on]="" [off]="--no-wide-pass")
methods=("wskp3:wskp --layers 3" "wskp6:wskp --layers 6" "afn:afn")
for seq in "$@"; do
    s=$(basename "$seq")
    for pair in first mean; do
        for mode in on off; do
            line="$s, --pair $pair, $mode:"
            for entry in "${methods[@]}"; do
                name=${entry%%:*}
                o="$out/$mode-$pair/$s/$name"
                rm -rf "$o"
                mkdir -p "$(dirname "$o")"
                # shellcheck disable=SC2086
                "$M" denoise --method ${entry#*:} --pair "$pair" ${flags[$mode]} "$seq" -o "$o" >/dev/null 2>"$out/err" ||
                    { cat "$out/err" >&2; exit 1; }
                r=$("$M" score -r "$seq/ref" "$o" | tail -1)
                line="$line $name $(echo "$r" | awk '{printf "%.2f (%.4f)", $3, $8}')"
            done
            echo "$line"
        done
    done
    [ -d "$out/oidn/$s" ] || "$PY" "$HERE/oidn_denoise.py" "$seq" -o "$out/oidn/$s" --quality high >/dev/null
    args=()
    for entry in "${methods[@]}"; do
        name=${entry%%:*}
        args+=("$name-off=$out/off-first/$s/$name" "$name-on=$out/on-first/$s/$name")
    done
    "$PY" "$HERE/blotch.py" "$seq" "${args[@]}" "oidn-high=$out/oidn/$s"
done
