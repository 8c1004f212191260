#!/usr/bin/env bash
# Run the whole test suite. pytest's exit code 5 (no tests collected) counts as a failure.
# The test files are spread over TORCHHAND_TEST_WORKERS processes (pytest-xdist, default 2: the suite's machine has
# 2 cores; each file runs whole in one process, so its module fixtures are built once; the longest files start first,
# tests/conftest.py's LONG_FILES). Each process runs torch on
# one thread unless OMP_NUM_THREADS says otherwise; tests whose results depend on the thread count pin it
# themselves. TORCHHAND_TEST_WORKERS=1 (or no pytest-xdist) runs everything in this process.
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
WORKERS=${TORCHHAND_TEST_WORKERS:-2}
PARALLEL=()
if [ "$WORKERS" -gt 1 ] && "$PY" -c "import xdist" >/dev/null 2>&1; then
  PARALLEL=(-n "$WORKERS" --dist loadfile --no-loadscope-reorder)
  export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
fi
"$PY" -m pytest -q -p no:cacheprovider "${PARALLEL[@]}" "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "test: no tests were collected" >&2
  exit 1
fi
exit "$rc"
