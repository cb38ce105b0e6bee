#!/bin/bash
# One WSKP-6 training step (forward, SMAPE, the fused filter's gradient,
# backward, Adam) on a batch of 8 crops of 128x128, ours and PyTorch's
# (eager, CPU, the same network and threads), one after the other on this
# machine: median of REPS steps each.
#
#     bash tools/setup-peers.sh                 # PyTorch, once
#     bash tools/train-step-side-by-side.sh [THREADS] [REPS]
set -euo pipefail
cd "$(dirname "$0")/.."
THREADS=${1:-2}
REPS=${2:-20}
echo "CPU: $(lscpu | sed -n 's/^Model name: *//p'); load average $(cut -d' ' -f1-3 /proc/loadavg)"
cargo build --release -q -p mcdenoise-benches --example profile_train
./target/release/examples/profile_train 6 "$THREADS" "$REPS" 8 128
OMP_WAIT_POLICY=PASSIVE tools/.venv-peers/bin/python tools/torch_wskp.py time --threads "$THREADS" --reps "$REPS" --train-only
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
