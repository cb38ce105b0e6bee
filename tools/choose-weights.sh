#!/usr/bin/env bash
# Two weights files of one model side by side on the generator's held-out
# scenes, with the denoiser as users run it (fallback on): the `val` scenes
# and the `hi` scenes no run trains on (hi_0044-hi_0063), one estimate
# (`--pair first`) and the pair (the default). Prints each scene's PSNR dB
# and relMSE before and after, then the mean PSNR of each part and how many
# of its scenes got better. The rule docs/training.md applies: bundle the
# new file if it wins here; look at the foreign set only afterwards.
#
# Usage: bash tools/choose-weights.sh MODEL OLD.safetensors NEW.safetensors [DATA]
#   MODEL: wskp3, wskp6 or afn; DATA: the generator's data (default /work/data/gen)
#   MCDENOISE=path/to/binary (default target/release/mcdenoise)
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(dirname "$HERE")"
BIN="${MCDENOISE:-$ROOT/target/release/mcdenoise}"
[ $# -ge 3 ] || { sed -n '2,12p' "$0" >&2; exit 2; }
MODEL="$1"; OLD="$2"; NEW="$3"; DATA="${4:-/work/data/gen}"
case "$MODEL" in
    wskp3) method=(--method wskp --layers 3) ;;
    wskp6) method=(--method wskp --layers 6) ;;
    afn) method=(--method afn) ;;
    *) echo "choose-weights: MODEL must be wskp3, wskp6 or afn, not '$MODEL'" >&2; exit 2 ;;
esac
for f in "$OLD" "$NEW"; do [ -f "$f" ] || { echo "choose-weights: no weights file $f" >&2; exit 2; }; done
[ -x "$BIN" ] || { echo "choose-weights: no binary $BIN (cargo build --release, or MCDENOISE=...)" >&2; exit 2; }
seqs=()
for d in "$DATA"/val/val_* "$DATA"/hi/hi_00{44..63}; do [ -d "$d/ref" ] && seqs+=("$d"); done
[ ${#seqs[@]} -gt 0 ] || { echo "choose-weights: no held-out scenes under $DATA/val or $DATA/hi" >&2; exit 2; }
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

# PSNR and relMSE of one file on one scene, or nothing where PSNR is not
# finite (a black reference).
run() {
    local w="$1" seq="$2" pair="$3" o="$tmp/o"
    rm -rf "$o"
    "$BIN" denoise --quiet --threads 2 "${method[@]}" --weights "$w" --pair "$pair" "$seq" -o "$o"
    "$BIN" score --reference "$seq/ref" "$o" --json | tail -1 | python3 -c '
import json, sys
m = json.load(sys.stdin)["mean"]
if m["psnr"] is not None:
    print("%.3f %.5f" % (m["psnr"], m["relmse"]))'
}

for pair in first mean; do
    echo "== $MODEL, --pair $pair: scene, PSNR dB and relMSE before -> after"
    for seq in "${seqs[@]}"; do
        a="$(run "$OLD" "$seq" "$pair")"; b="$(run "$NEW" "$seq" "$pair")"
        if [ -n "$a" ] && [ -n "$b" ]; then echo "$(basename "$seq") $a $b"; fi
    done | tee "$tmp/$pair.txt"
    awk '{ g = ($1 ~ /^val/) ? "val" : "hi"; d = $4 - $2; n[g]++; s[g] += d; a[g] += $2; b[g] += $4; if (d > 0) w[g]++ }
         END { split("val hi", order, " ")
               for (k = 1; k <= 2; k++) { g = order[k]; if (n[g])
                   printf "%s (%d): mean PSNR %.2f -> %.2f dB, %+.3f, better on %d of %d\n",
                          g, n[g], a[g] / n[g], b[g] / n[g], s[g] / n[g], w[g] + 0, n[g] } }' \
        "$tmp/$pair.txt"
done
