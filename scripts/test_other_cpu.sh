#!/usr/bin/env bash
# Run the numerically sensitive tests again under another CPU's arithmetic: torch without its vector kernels,
# OpenBLAS's Sandy Bridge kernels and MKL's compatible branch (code paths no x86-64 CPU picks by default, so they
# differ from this machine's, whatever it is). Tests that assert a search, a plan or a solver's verdict must pass
# here too: they decide with margins, not with the last bit. The command line pins its own profile
# (docs/synthesis.md), so the README main command's digest must not change either.
# Other settings: OTHER_CPU="ATEN_CPU_CAPABILITY=avx2 OPENBLAS_CORETYPE=Zen MKL_CBWR=AVX2" bash scripts/test_other_cpu.sh
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
OTHER_CPU=${OTHER_CPU:-"ATEN_CPU_CAPABILITY=default OPENBLAS_CORETYPE=Sandybridge MKL_CBWR=COMPATIBLE"}
TESTS=(
  tests/torchhand/test_numerics.py
  tests/torchhand/test_synthesis.py tests/torchhand/test_synthesis_output.py tests/torchhand/test_synth_fast_paths.py
  tests/torchhand/test_synth_derivs.py tests/torchhand/test_reconstruct.py
  tests/torchhand/test_grasp.py tests/torchhand/test_plan.py tests/torchhand/test_qp.py tests/torchhand/test_dense_qp.py
  tests/kernels/test_convex_qp.py
  tests/torchhand/test_manipulate.py tests/torchhand/test_manipulate_added.py tests/torchhand/test_manipulate_extras.py
  tests/torchhand/test_liu_scenes.py tests/torchhand/test_liu_roll.py
  tests/torchhand/test_mount.py tests/render/test_render.py tests/torchhand/test_node_graphs.py
)
echo "test_other_cpu: $OTHER_CPU"
# the files spread over TORCHHAND_TEST_WORKERS processes as in scripts/test.sh
WORKERS=${TORCHHAND_TEST_WORKERS:-2}
PARALLEL=()
if [ "$WORKERS" -gt 1 ] && "$PY" -c "import xdist" >/dev/null 2>&1; then
  PARALLEL=(-n "$WORKERS" --dist loadfile --no-loadscope-reorder)
  export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
fi
# The ManipNet mug's expected failure (issue of grid normals, minutes of search) is left to the main run.
env $OTHER_CPU "$PY" -m pytest -q -p no:cacheprovider "${PARALLEL[@]}" "${TESTS[@]}" \
  --deselect tests/torchhand/test_synthesis.py::test_manipnet_mug_segment_yields_checked_solutions "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "test_other_cpu: no tests were collected" >&2
  exit 1
fi
exit "$rc"
