#!/usr/bin/env bash
# End-to-end time per frame as a user sees it: `mcdenoise denoise` on a
# sequence of 1280x720 EXR frames (the bundled sample tiled, every channel,
# f32, ZIP), wall time from the first read to the last write over the
# frames, with the kernels, read and write beside it, for every method and
# precision; then Intel Open Image Denoise (pyoidn) on the same frame size
# and threads, in the same run. docs/performance.md quotes its output.
#
# Usage: bash tools/speed-e2e.sh [THREADS] [FRAMES_DIR]
#   THREADS default 2; FRAMES_DIR default: the sample tiled to 1280x720 into
#   a temporary directory (tools/tile_sample.py, needs tools/.venv).
#   METHODS="none ta atrous sure-atrous wskp3 wskp6 afn"  PRECISIONS="f32 f16 fixed"
#   Needs target/release/mcdenoise (or $MCDENOISE); OIDN: tools/.venv-peers.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
THREADS="${1:-2}"
BIN="${MCDENOISE:-$HERE/../target/release/mcdenoise}"
[ -x "$BIN" ] || (cd "$HERE/.." && cargo build --release)
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
FR="${2:-}"
if [ -z "$FR" ]; then
    FR="$tmp/frames"
    "$HERE/.venv/bin/python" "$HERE/tile_sample.py" "$FR" --size 1280x720 --frames 8 >/dev/null
fi
METHODS="${METHODS:-none ta atrous sure-atrous wskp3 wskp6 afn}"
PRECISIONS="${PRECISIONS:-f32 f16 fixed}"
echo "CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) logical; threads $THREADS"
echo "frames: $(ls "$FR"/*.exr | wc -l) of $("$BIN" inspect "$(ls "$FR"/*.exr | head -1)" | sed -n 2p | grep -o 'data window [0-9x]*')"
printf '%-12s %-6s %10s %10s %10s %10s\n' method prec "wall ms" kernels read write
for m in $METHODS; do
    case $m in
        wskp3) args=(--method wskp --layers 3) ;;
        wskp6) args=(--method wskp --layers 6) ;;
        *) args=(--method "$m") ;;
    esac
    for p in $PRECISIONS; do
        [ "$m" = none ] && [ "$p" != f32 ] && [ "$p" != f16 ] && continue
        rm -rf "$tmp/out"
        "$BIN" denoise "${args[@]}" --precision "$p" --threads "$THREADS" --json "$FR" -o "$tmp/out" >"$tmp/j.json"
        python3 - "$m" "$p" "$tmp/j.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[3]))
print('%-12s %-6s %10.1f %10.1f %10.1f %10.1f' % (sys.argv[1], sys.argv[2], j['ms_per_frame'], j['kernel_ms_per_frame'],
      j['read_ms_per_frame'], j['write_ms_per_frame']))
PY
    done
done
PEER="$HERE/.venv-peers/bin/python"
if [ -x "$PEER" ]; then
    for q in fast high; do
        echo "OIDN $q (device and filter committed once, HDR colour + albedo + normal, in memory): $("$PEER" "$HERE/oidn_denoise.py" --time 1280x720 --threads "$THREADS" --quality "$q" | tail -1)"
    done
else
    echo "OIDN: no tools/.venv-peers (bash tools/setup-peers.sh PEERS=oidn)"
fi
