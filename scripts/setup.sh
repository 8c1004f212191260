#!/usr/bin/env bash
# Install everything torchhand needs on a fresh Debian/Ubuntu machine with Python >= 3.11:
# system libraries for headless rendering (Mesa's EGL and OSMesa), the CPU build of torch 2.13.0, and torchhand
# itself (editable, with the test extras; NumPy 2), then a second environment with NumPy 1.x for the extras that
# still need it (qpth, Blender). Safe to run again: every step is idempotent.
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
# >= 2.5.1 (a GPU machine, say) keeps it.
if ! "$PY" -c "import torch, sys; v=tuple(int(x) for x in torch.__version__.split('+')[0].split('.')[:3]); sys.exit(v < (2, 5, 1))" 2>/dev/null; then
  "$PY" -m pip install -q "torch==2.13.0"
fi
# pyrender (unmaintained since 2021) is replaced by its maintained fork pyrender2, which installs the same `pyrender`
# package: an environment that still has the old distribution loses both before the fork goes in (they share files).
if "$PY" -m pip show pyrender >/dev/null 2>&1; then
  echo "setup: replacing pyrender with its maintained fork pyrender2"
  "$PY" -m pip uninstall -q -y pyrender pyrender2 >/dev/null 2>&1 || true
fi
"$PY" -m pip install -q -e ".[test]"
# Optional: Chromium from Debian, for the viewer's browser test (torchhand view, driven by Playwright); without it
# that test is skipped. SETUP_BROWSER=0 skips this step.
if [ "${SETUP_BROWSER:-1}" != 0 ] && ! command -v chromium >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium; } \
      >/dev/null 2>&1 || echo "setup: optional chromium not installed; the viewer's browser test will be skipped"
  fi
fi
# Optional: Ray (the extra [ray], about 80 MB), for `torchhand batch --ray` and the tests that run a batch on a local
# Ray instance. Not fatal: without it those tests are skipped. SETUP_RAY=0 skips this step.
if [ "${SETUP_RAY:-1}" != 0 ]; then
  "$PY" -m pip install -q -e ".[ray]" >/dev/null 2>&1 || true
  "$PY" -c "import ray" >/dev/null 2>&1 \
    || echo "setup: optional ray not installed; the Ray batch tests will be skipped"
fi
# The second environment, NumPy 1.x (SETUP_NUMPY1=0 skips it): the optional extras that still need NumPy < 2, the qpth
# adapter (extra [qpth]) and Blender as a Python module (extra [blender]: bpy 4.5, a 370 MB download, Python 3.11
# only, used by the FBX export and by the tests that open written files with Blender's own importers;
# SETUP_BLENDER=0 leaves it out). scripts/test_numpy1.sh runs their tests there; `torchhand export --format fbx`
# in the main environment finds this Blender through TORCHHAND_BLENDER=$ENV1/bin/python.
if [ "${SETUP_NUMPY1:-1}" != 0 ]; then
  ENV1=${TORCHHAND_NUMPY1_ENV:-.venv-numpy1}
  [ -x "$ENV1/bin/python" ] || "$PY" -m venv "$ENV1"
  P1="$ENV1/bin/python"
  "$P1" -c "import torch" >/dev/null 2>&1 || "$P1" -m pip install -q "torch==2.13.0"
  "$P1" -m pip install -q -e ".[test,qpth]" "numpy<2"
  if [ "${SETUP_BLENDER:-1}" != 0 ]; then
    "$P1" -m pip install -q -e ".[blender]" "numpy<2" >/dev/null 2>&1 || true
    "$P1" -c "import bpy" >/dev/null 2>&1 \
      || echo "setup: optional bpy (Blender 4.5, Python 3.11 only) not installed; the Blender tests will be skipped"
  fi
  "$P1" -c "import numpy, qpth; print('setup: NumPy 1 environment', '$ENV1', 'numpy', numpy.__version__)"
fi
command -v pyenv >/dev/null 2>&1 && pyenv rehash || true
"$PY" -c "import torchhand, torchhand.kernels; print('setup: torchhand', torchhand.__version__, 'ready')"
