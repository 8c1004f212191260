#!/usr/bin/env bash
# The GPU figures of BENCHMARKS.md ("On a GPU") in one run, for a machine lent with a GPU: the CUDA tests, the node-test
# bench, and box-turn's seeds as one batched run, each writing its JSON and log under OUT (default ./gpu_figures).
#
#   bash scripts/gpu_figures.sh [OUT]
#
# Settings (environment): DEVICE (cuda), SEEDS ("16 64": one batch of seeds 0..K-1 per K), MAX_NODES (6000 per seed),
# SOLUTIONS (3), ALONE (2: seeds also run one at a time on the device, for the identical-files check), NODE_BATCH
# ("1024 16384 65536"), FILL_FRAMES (mug1's frames for the fill step, 290:420), FINISH_PATHS (8: paths the finish step
# finishes one after another and side by side), STEPS (tests nodes batch fill finish: the steps to run). Each step is bounded by STEP_TIMEOUT seconds
# (540) and a failed or timed-out step does not stop the next; the script's exit status is the first failure's.
# The one-job-at-a-time CPU rate the batch is compared with is BENCHMARKS.md's (the same command with --device cpu).
# A lend of 15 minutes holds less than all steps: take them in the issue's order of need, e.g.
#   STEPS="tests nodes" STEP_TIMEOUT=240 bash scripts/gpu_figures.sh, then STEPS=batch SEEDS=16 MAX_NODES=11000 ALONE=1.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-gpu_figures}
DEVICE=${DEVICE:-cuda}
SEEDS=${SEEDS:-16 64}
MAX_NODES=${MAX_NODES:-6000}
SOLUTIONS=${SOLUTIONS:-3}
ALONE=${ALONE:-2}
NODE_BATCH=${NODE_BATCH:-1024 16384 65536}
FILL_FRAMES=${FILL_FRAMES:-290:420}
FINISH_PATHS=${FINISH_PATHS:-8}
STEPS=${STEPS:-tests nodes batch fill finish}
STEP_TIMEOUT=${STEP_TIMEOUT:-540}
PY=${PYTHON:-python3}
mkdir -p "$OUT"
"$PY" - "$OUT/machine.json" <<'EOF'
import json, platform, sys
import torch
info = {"python": platform.python_version(), "torch": torch.__version__, "cuda": torch.version.cuda,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}
json.dump(info, open(sys.argv[1], "w"), indent=1)
print("machine:", info)
EOF
status=0
step() {   # step NAME COMMAND...: run one step with its log, remember the first failure
  local name=$1
  shift
  echo "== $name: $*"
  local t0=$SECONDS
  timeout "$STEP_TIMEOUT" "$@" >"$OUT/$name.log" 2>&1
  local rc=$?
  echo "== $name: exit $rc in $((SECONDS - t0)) s (log: $OUT/$name.log)"
  tail -n 15 "$OUT/$name.log"
  if [ "$rc" -ne 0 ] && [ "$status" -eq 0 ]; then status=$rc; fi
}
for s in $STEPS; do
  case $s in
    tests) step tests "$PY" -m pytest -q -p no:cacheprovider tests/kernels tests/torchhand/test_multi_search.py \
             tests/torchhand/test_step.py tests/torchhand/test_fill_pieces.py tests/torchhand/test_node_graphs.py \
             tests/torchhand/test_finishing.py tests/torchhand/test_reconstruct.py -k cuda ;;
    nodes) # shellcheck disable=SC2086
           step nodes "$PY" scripts/bench_synthesis.py nodes --device "$DEVICE" --batch $NODE_BATCH \
             --json "$OUT/nodes.json" ;;
    # shellcheck disable=SC2086
    batch) step batch "$PY" scripts/bench_synthesis.py batch --device "$DEVICE" --scenes box-turn \
             --batch-seeds $SEEDS --solutions "$SOLUTIONS" --max-nodes "$MAX_NODES" --alone "$ALONE" \
             --json "$OUT/batch.json" ;;
    fill) step fill "$PY" scripts/bench_synthesis.py fill --device "$DEVICE" --fill-frames "$FILL_FRAMES" \
             --max-nodes "$MAX_NODES" --stall-nodes 2000 --solutions 2 --json "$OUT/fill.json" ;;
    finish) step finish "$PY" scripts/bench_synthesis.py finish --device "$DEVICE" --scenes box-turn \
             --solutions "$FINISH_PATHS" --repeats 2 --json "$OUT/finish.json" ;;
    *) echo "gpu_figures: unknown step '$s' (tests, nodes, batch, fill, finish)" >&2; exit 2 ;;
  esac
done
exit "$status"
