#!/usr/bin/env bash
# The history rejection's scales (docs/quality.md, "The history rejection
# at three scales"): WSKP-6, AFN and WSKP-3 with --ta-reject-scales 1, 2
# and 3, one estimate (--pair first; PAIR=mean below), on every rendered
# training scene of the generator with a moving light (an emitter with
# keyframes, or an emissive shape with them) and on the sequences given;
# per scene the mean PSNR
# over its frames, then per method and scale count the mean change from
# one scale and the worst and best scene.
#
#   bash tools/reject-scales.sh GEN_DIR OUT_DIR [SEQ_DIR...]
#
# GEN_DIR as tools/render-train.sh makes it (scenes/*.json, train/, val/),
# or - for the SEQ_DIRs alone; OUT_DIR keeps the outputs
# (OUT_DIR/SCENE/{1,2,3}/METHOD) and the table (OUT_DIR/scores.txt);
# outputs that exist are kept. SCALES="1 2 3", METHODS="wskp6 afn wskp3"
# and PAIR=first (or mean: the pair's mean, where the frames carry B.*;
# use another OUT_DIR for it) choose. OPTION=--ta-relight VALUES="off on"
# compares another option's values instead (the changes are from the first
# value; docs/quality.md, "The history relit where a light moved"). Needs target/release/mcdenoise (or
# $MCDENOISE) and bash 4 or later. About 2 s a scene and method on a
# 2-core machine (8 frames of 192x144). Sequences are named by their
# folder's name, which must differ.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
[ $# -ge 2 ] || { sed -n '2,/^set -euo/p' "$0" | grep '^#' >&2; exit 2; }
M=${MCDENOISE:-$HERE/../target/release/mcdenoise}
[ -x "$M" ] || { echo "reject-scales.sh: no $M (cargo build --release -p mcdenoise-cli)" >&2; exit 1; }
gen=$1; out=$2; shift 2
SCALES=${SCALES:-1 2 3}; METHODS=${METHODS:-wskp6 afn wskp3}; PAIR=${PAIR:-first}
OPTION=${OPTION:---ta-reject-scales}
if [ "$OPTION" = --ta-reject-scales ]; then
    case " $SCALES " in *" 1 "*) ;; *) echo "reject-scales.sh: SCALES must include 1 (the changes are from it)" >&2; exit 2 ;; esac
    VALUES="1 ${SCALES//1/}"
fi
VALUES=${VALUES:?reject-scales.sh: VALUES names the values of $OPTION to compare}
base=${VALUES%% *}
mkdir -p "$out"
seqs=()
if [ "$gen" != - ]; then
    # (An assignment, so that a failing scan stops the script.)
    list=$(python3 - "$gen" <<'EOF'
import glob, json, os, sys
gen = sys.argv[1]
for f in sorted(glob.glob(os.path.join(gen, 'scenes', 'train_*.json'))):
    name = os.path.basename(f)[:-5]
    d = os.path.join(gen, 'train', name)
    if not os.path.isdir(os.path.join(d, 'ref')):
        continue
    s = json.load(open(f))
    if any('keyframes' in e for e in s.get('emitters', [])) or \
       any('keyframes' in x and 'emitter' in x for x in s.get('shapes', [])):
        print(d)
EOF
)
    [ -z "$list" ] || mapfile -t seqs <<<"$list"
fi
seqs+=("$@")
[ ${#seqs[@]} -gt 0 ] || { echo "reject-scales.sh: no sequence (no rendered scene with a moving light in $gen)" >&2; exit 1; }
echo "${#seqs[@]} sequences" >&2
: > "$out/scores.txt"
for seq in "${seqs[@]}"; do
    s=$(basename "$seq")
    for k in $VALUES; do
        line="$s $k"
        for m in $METHODS; do
            case $m in
                wskp6) a=(--method wskp --layers 6) ;;
                wskp3) a=(--method wskp --layers 3) ;;
                afn) a=(--method afn) ;;
                *) echo "reject-scales.sh: unknown method $m" >&2; exit 2 ;;
            esac
            o="$out/$s/$k/$m"
            if [ ! -d "$o" ]; then
                "$M" denoise "${a[@]}" --pair "$PAIR" "$OPTION" "$k" "$seq" -o "$o.tmp" >/dev/null 2>"$out/err" ||
                    { cat "$out/err" >&2; exit 1; }
                mv "$o.tmp" "$o"
            fi
            line="$line $m $("$M" score -r "$seq/ref" "$o" | tail -1 | awk '{print $3}')"
        done
        echo "$line" | tee -a "$out/scores.txt"
    done
done
python3 - "$out/scores.txt" "$base" "$OPTION" <<'EOF'
import collections, math, sys
rows = collections.defaultdict(dict)
for line in open(sys.argv[1]):
    f = line.split()
    rows[f[0]][f[1]] = {f[i]: float(f[i + 1]) for i in range(2, len(f), 2)}
base, option = sys.argv[2], sys.argv[3]
scales = [base] + sorted({k for r in rows.values() for k in r} - {base})
methods = [m for m in next(iter(rows.values()))[base]]
print('change from %s %s, PSNR dB, mean over %d sequences (worst, best):' % (option, base, len(rows)))
for k in scales[1:]:
    parts = []
    for m in methods:
        d = sorted((r[k][m] - r[base][m], s) for s, r in rows.items()
                   if k in r and base in r and math.isfinite(r[k][m]) and math.isfinite(r[base][m]))
        if d:
            parts.append('%s %+.3f (%+.3f %s, %+.3f %s)' % (m, sum(x for x, _ in d) / len(d), d[0][0], d[0][1], d[-1][0], d[-1][1]))
    print('  %s %s: %s' % (option, k, '; '.join(parts)))
EOF
