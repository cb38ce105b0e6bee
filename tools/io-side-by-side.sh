#!/bin/bash
# Reading and writing a 1280x720 frame (the bundled sample tiled, 18 f32
# channels, ZIP): mcdenoise's loader and writer (criterion, benches/benches/io.rs)
# and OpenEXR's own (tools/exr_peer_time.py), one after the other on the same
# file and machine.
#
#     bash tools/setup-render.sh      # OpenEXR's Python package, once
#     bash tools/io-side-by-side.sh
set -euo pipefail
cd "$(dirname "$0")/.."
echo "CPU: $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) threads; load average $(cut -d' ' -f1-3 /proc/loadavg)"
cargo bench -q -p mcdenoise-benches --bench io 2>&1 | grep -E "^io/|time:"
for t in 1 2; do
    tools/.venv/bin/python tools/exr_peer_time.py target/bench-io-frame.exr --threads "$t"
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
