#!/usr/bin/env bash
# Install everything torchhand needs on a fresh Debian/Ubuntu machine with Python >= 3.11:
# system libraries for headless rendering (Mesa's EGL and OSMesa), the CPU build of torch 2.13.0, and torchhand
# itself (editable, with the test extras). Safe to run again: every step is idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  pkgs="libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libglx-mesa0 libosmesa6 libglu1-mesa"
  missing=""
  for p in $pkgs; do
    dpkg-query -W -f='${db:Status-Status}' "$p" 2>/dev/null | grep -qx installed || missing="$missing $p"
  done
  if [ -n "$missing" ]; then
    echo "setup: installing system packages: $missing"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $missing >/dev/null
  fi
else
  echo "setup: not root or no apt-get; make sure Mesa's EGL/OSMesa (libegl1, libosmesa6) are installed for rendering"
fi

# torch first, pinned, so that no dependency pulls another (CUDA) build. A machine that already has a torch
# >= 2.4 (a GPU machine, say) keeps it.
if ! "$PY" -c "import torch, sys; v=tuple(int(x) for x in torch.__version__.split('+')[0].split('.')[:2]); sys.exit(v < (2, 4))" 2>/dev/null; then
  "$PY" -m pip install -q "torch==2.13.0"
fi
"$PY" -m pip install -q -e ".[test]"
# Optional: Blender as a Python module (about 370 MB download, 800 MB installed), used only by the tests that import
# written BVH files with Blender's own importer. Not fatal: without it those tests are skipped.
# SETUP_BLENDER=0 skips this step.
if [ "${SETUP_BLENDER:-1}" != 0 ]; then
  "$PY" -m pip install -q -e ".[blender]" >/dev/null 2>&1 || true
  "$PY" -c "import bpy" >/dev/null 2>&1 \
    || echo "setup: optional bpy (Blender 4.5, Python 3.11 only) not installed; the Blender tests will be skipped"
fi
# Optional: Ray (the extra [ray], about 80 MB), for `torchhand batch --ray` and the tests that run a batch on a local
# Ray instance. Not fatal: without it those tests are skipped. SETUP_RAY=0 skips this step.
if [ "${SETUP_RAY:-1}" != 0 ]; then
  "$PY" -m pip install -q -e ".[ray]" >/dev/null 2>&1 || true
  "$PY" -c "import ray" >/dev/null 2>&1 \
    || echo "setup: optional ray not installed; the Ray batch tests will be skipped"
fi
command -v pyenv >/dev/null 2>&1 && pyenv rehash || true
"$PY" -c "import torchhand, torchhand.kernels; print('setup: torchhand', torchhand.__version__, 'ready')"
