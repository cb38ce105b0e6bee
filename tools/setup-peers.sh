#!/usr/bin/env bash
# Sets up the Python environment of the peers (PyTorch, Intel Open Image
# Denoise) in tools/.venv-peers, idempotently. Usage: bash tools/setup-peers.sh
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$HERE/.venv-peers"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
if ! "$VENV/bin/python" -c "import torch, pyoidn, safetensors, OpenEXR, numpy" 2>/dev/null; then
    "$VENV/bin/pip" install --quiet -r "$HERE/requirements-peers.txt"
fi
"$VENV/bin/python" -c "import torch, pyoidn; print('[setup-peers] torch', torch.__version__, '- pyoidn ok')"
