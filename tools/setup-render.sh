#!/usr/bin/env bash
# Sets up everything tools/render.py needs, idempotently, on a fresh Debian
# machine:
#
#   1. a Python virtual environment in tools/.venv with the pinned packages of
#      tools/requirements-render.txt (Mitsuba 3, Dr.Jit, OpenEXR, NumPy);
#   2. Debian's libllvm19 (when apt-get can install it), which Mitsuba's fast
#      `llvm_ad_rgb` variant loads at run time through DRJIT_LIBLLVM_PATH;
#   3. tools/render.env, a small shell file exporting DRJIT_LIBLLVM_PATH and
#      MCDENOISE_MI_VARIANT (llvm_ad_rgb, or scalar_rgb when no libLLVM).
#
# Usage:   bash tools/setup-render.sh            (from anywhere)
# Then:    tools/.venv/bin/python tools/render.py --help
#
# render.py finds libLLVM by itself too (env var, then the usual system
# paths), so sourcing render.env is optional. Running this script again only
# re-checks; it reinstalls nothing that is already in place.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$HERE/.venv"
REQ="$HERE/requirements-render.txt"
ENV_FILE="$HERE/render.env"
PYTHON="${PYTHON:-python3}"

log() { printf '[setup-render] %s\n' "$*"; }

run_as_root() {
    if [ "$(id -u)" -eq 0 ]; then
        "$@"
    elif command -v sudo >/dev/null 2>&1; then
        sudo "$@"
    else
        return 1
    fi
}

# --- 1. Python virtual environment -----------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
    log "creating virtual environment in $VENV"
    if ! "$PYTHON" -m venv "$VENV"; then
        log "python3 -m venv failed; trying to install python3-venv"
        run_as_root apt-get install -y python3-venv 2>/dev/null || true
        "$PYTHON" -m venv "$VENV"
    fi
fi

if "$VENV/bin/python" - "$REQ" <<'PYEOF'
import sys
from importlib import metadata
ok = True
for line in open(sys.argv[1]):
    line = line.split('#', 1)[0].strip()
    if not line:
        continue
    name, _, want = line.partition('==')
    try:
        have = metadata.version(name)
    except metadata.PackageNotFoundError:
        have = None
    if have != want:
        ok = False
sys.exit(0 if ok else 1)
PYEOF
then
    log "pinned Python packages already installed"
else
    log "installing pinned Python packages from $REQ"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip
    "$VENV/bin/python" -m pip install --quiet -r "$REQ"
fi

# --- 2. libLLVM for the llvm_ad_rgb variant -----------------------------------

find_libllvm() {
    local f
    if [ -n "${DRJIT_LIBLLVM_PATH:-}" ] && [ -f "$DRJIT_LIBLLVM_PATH" ]; then
        echo "$DRJIT_LIBLLVM_PATH"; return 0
    fi
    if command -v dpkg >/dev/null 2>&1 && dpkg -s libllvm19 >/dev/null 2>&1; then
        f="$( (dpkg -L libllvm19 | grep -E '/libLLVM-19\.so$'; dpkg -L libllvm19 | grep -E '/libLLVM\.so\.19') | head -n 1 || true)"
        if [ -n "$f" ] && [ -f "$f" ]; then echo "$f"; return 0; fi
    fi
    for f in /usr/lib/x86_64-linux-gnu/libLLVM-19.so /usr/lib/aarch64-linux-gnu/libLLVM-19.so \
             /usr/lib/llvm-19/lib/libLLVM.so /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1; do
        if [ -f "$f" ]; then echo "$f"; return 0; fi
    done
    return 1
}

LIBLLVM="$(find_libllvm || true)"
if [ -z "$LIBLLVM" ] && command -v apt-get >/dev/null 2>&1; then
    log "installing libllvm19 with apt-get"
    export DEBIAN_FRONTEND=noninteractive
    if ! apt-cache policy libllvm19 2>/dev/null | grep -q 'Candidate: [0-9]'; then
        run_as_root apt-get update -qq || true
    fi
    if run_as_root apt-get install -y -qq libllvm19 >/dev/null; then
        LIBLLVM="$(find_libllvm || true)"
    else
        log "apt-get could not install libllvm19"
    fi
fi

if [ -n "$LIBLLVM" ]; then
    VARIANT=llvm_ad_rgb
    log "using libLLVM at $LIBLLVM (variant $VARIANT)"
else
    VARIANT=scalar_rgb
    log "WARNING: no libLLVM-19 found and none could be installed;"
    log "WARNING: falling back to the scalar_rgb variant (correct but much slower)."
fi

# --- 3. environment file + smoke test ------------------------------------------
{
    echo "# Written by tools/setup-render.sh; source it before tools/render.py (optional)."
    if [ -n "$LIBLLVM" ]; then echo "export DRJIT_LIBLLVM_PATH='$LIBLLVM'"; fi
    echo "export MCDENOISE_MI_VARIANT='$VARIANT'"
} > "$ENV_FILE"

DRJIT_LIBLLVM_PATH="${LIBLLVM:-}" MCDENOISE_MI_VARIANT="$VARIANT" "$VENV/bin/python" - <<'PYEOF'
import os
import mitsuba as mi
variant = os.environ['MCDENOISE_MI_VARIANT']
mi.set_variant(variant)
scene = mi.load_dict({'type': 'scene', 'sphere': {'type': 'sphere'},
                      'light': {'type': 'constant'},
                      'integrator': {'type': 'path'},
                      'sensor': {'type': 'perspective',
                                 'film': {'type': 'hdrfilm', 'width': 8, 'height': 8,
                                          'rfilter': {'type': 'box'}}}})
img = mi.render(scene, spp=4)
print('[setup-render] smoke test ok: mitsuba %s, variant %s, image %s'
      % (mi.__version__, variant, tuple(img.shape)))
PYEOF
log "done. Render with: $VENV/bin/python $HERE/render.py <scene.json> --out <dir>"
