#!/usr/bin/env bash
# Sets up the Python environment of the peers (PyTorch WSKP, Intel Open Image
# Denoise) in tools/.venv-peers from tools/requirements-peers.txt. Idempotent:
# a second run finds every pinned package installed and downloads nothing.
# Usage: bash tools/setup-peers.sh          (PyTorch and OIDN)
#        PEERS=oidn bash tools/setup-peers.sh (OIDN only: no 3 GB of torch)
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$HERE/.venv-peers"
REQ="$HERE/requirements-peers.txt"
if [ "${PEERS:-all}" = oidn ]; then
    [ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
    grep -E '^(pyoidn|numpy|OpenEXR)==' "$REQ" > "$VENV/oidn-requirements.txt"
    "$VENV/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check -r "$VENV/oidn-requirements.txt"
    "$VENV/bin/python" -c "import importlib.metadata as md, pyoidn; print('[setup-peers] ok: pyoidn', md.version('pyoidn'))"
    exit 0
fi
if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup-peers] creating $VENV"
    python3 -m venv "$VENV"
fi
# Already satisfied pins are skipped without any download; --no-cache-dir keeps
# a second copy of the large torch wheels out of pip's cache.
"$VENV/bin/pip" install --quiet --no-cache-dir --disable-pip-version-check -r "$REQ"
"$VENV/bin/python" - <<'PY'
import importlib.metadata as md
import torch, pyoidn, safetensors, numpy, OpenEXR  # noqa: F401
print('[setup-peers] ok: torch %s (%d threads), pyoidn %s, safetensors %s, numpy %s, OpenEXR %s'
      % (torch.__version__, torch.get_num_threads(), md.version('pyoidn'), md.version('safetensors'),
         numpy.__version__, md.version('OpenEXR')))
PY
