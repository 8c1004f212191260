#!/usr/bin/env bash
# The tests of the extras that still need NumPy < 2, in the second environment that scripts/setup.sh makes
# ($TORCHHAND_NUMPY1_ENV, default .venv-numpy1): the qpth adapter (extra [qpth]), everything that opens files with
# Blender (extra [blender], marker "blender", the FBX round trip), and a sample of the suite on NumPy 1.x.
# CI runs it after scripts/test.sh. qpth must import there (the adapter's tests would otherwise only skip).
set -uo pipefail
cd "$(dirname "$0")/.."
ENV1=${TORCHHAND_NUMPY1_ENV:-.venv-numpy1}
P1="$ENV1/bin/python"
if [ ! -x "$P1" ]; then
  echo "test_numpy1: no NumPy 1 environment at $ENV1 (run scripts/setup.sh)" >&2
  exit 1
fi
"$P1" -c "import numpy, qpth; assert numpy.__version__ < '2', numpy.__version__; print('test_numpy1: numpy', numpy.__version__)" || exit 1
"$P1" -m pytest -q -p no:cacheprovider \
  tests/torchhand/test_qp.py tests/torchhand/test_solvers.py tests/kernels/test_force_plan.py \
  tests/torchhand/test_export.py tests/torchhand/test_export_gltf.py tests/torchhand/test_result.py \
  tests/torchhand/test_check.py tests/torchhand/test_hand.py tests/torchhand/test_sdf.py \
  tests/torchhand/test_bvh.py tests/torchhand/test_bvh_blender.py tests/torchhand/test_export_blender.py \
  tests/torchhand/test_export_fbx.py tests/torchhand/test_splice_rigs.py "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "test_numpy1: no tests were collected" >&2
  exit 1
fi
exit "$rc"
