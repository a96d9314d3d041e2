#!/usr/bin/env bash
# The CUDA path, end to end, on a machine with a GPU: both recipes' tiny presets with
# --device cuda (every stage: data on the device, training, planning, evaluation), then
# GPU timings: the planner (small and paper model, the SimDist reference config) and one
# RSSM update (small and paper size). One log per step under $OUT (default
# /tmp/cuda_check); each step's last lines are printed.
#
# Usage:
#     bash benchmarks/cuda_check.sh            # all steps
#     LIMIT=120 bash benchmarks/cuda_check.sh  # at most 120 s a step
set -u
OUT=${OUT:-/tmp/cuda_check}
RUNS=${RUNS:-/tmp/cuda_check_runs}
mkdir -p "$OUT" "$RUNS"
export MUJOCO_GL=${MUJOCO_GL:-egl} PYTHONUNBUFFERED=1

step() {
    local name=$1 start rc
    shift
    echo "== $name: $*"
    start=$(date +%s)
    timeout -k 10 "${LIMIT:-300}" "$@" > "$OUT/$name.log" 2>&1
    rc=$?
    echo "   rc $rc, $(( $(date +%s) - start )) s"
    tail -n "${TAIL:-12}" "$OUT/$name.log" | cut -c1-200
}

timeout -k 5 120 python -c "import torch, torchrl, tensordict, mujoco; print('torch', torch.__version__,
torch.cuda.get_device_name(), 'torchrl', torchrl.__version__, 'tensordict',
tensordict.__version__, 'mujoco', mujoco.__version__)"
step quadruped_tiny python recipes/simdist_quadruped.py --preset tiny --device cuda \
    --output-dir "$RUNS/quadruped"
step twist_tiny python recipes/twist_dmc.py --preset tiny --device cuda \
    --output-dir "$RUNS/twist"
step planner_small python benchmarks/planner_latency.py --device cuda
step planner_paper python benchmarks/planner_latency.py --device cuda --size paper
step rssm_small python benchmarks/rssm_training.py --device cuda
step rssm_paper python benchmarks/rssm_training.py --device cuda --size paper --batch 16 \
    --length 64
