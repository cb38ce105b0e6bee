#!/usr/bin/env bash
# Checksums of every method's output in every precision (and both ISAs'
# widest path) on the bundled sample and two corpus scenes: run it before and
# after a change that must not change behaviour, and diff the two lists.
#
# Usage: bash tools/compare-outputs.sh OUT.txt   [MCDENOISE=path/to/binary]
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(dirname "$HERE")"
BIN="${MCDENOISE:-$ROOT/target/release/mcdenoise}"
OUT="$1"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
: > "$OUT"
inputs=("$ROOT/samples" "$ROOT/tests/fixtures/corpus/hdr" "$ROOT/tests/fixtures/corpus/glossy")
for input in "${inputs[@]}"; do
    for m in none ta atrous sure-atrous "wskp --layers 3" "wskp --layers 6" afn "afn --no-refine" cross; do
        for p in f32 f16 fixed; do
            [ "$m" = cross ] && [ "$p" != f32 ] && continue
            o="$tmp/o"
            rm -rf "$o"
            # shellcheck disable=SC2086
            "$BIN" denoise --quiet --threads 2 --method $m --precision "$p" "$input" -o "$o"
            sum=$(cat "$o"/*.exr | sha256sum | cut -c1-16)
            echo "$(basename "$input") $m $p $sum" | tee -a "$OUT"
        done
    done
done
