#!/bin/bash
# Runs on a lent GPU machine, from the repository root, after scripts/gpu-bench-prepare.sh and
# `scripts/gpu_continue_policy.py prepare` here:
#     device run, carry [".dev"], command "bash scripts/gpu-continue-run.sh [STEPS] [MINUTES] [ENVS]"
# Continues the prepared policy's PPO on CUDA (scripts/gpu_continue_policy.py train); the run directory
# comes back under $OUT/run.
set -u
export PYTHONUNBUFFERED=1
source scripts/gpu-pybullet.sh
python3 -c "import matplotlib, learning.rl.run" || exit 7
python3 scripts/gpu_continue_policy.py train --var worker/base_models/kuka/var.pt --steps "${1:-300000}" \
    --minutes "${2:-7}" --envs "${3:-14}" --out "$OUT/run"
echo "train rc=$? at $(elapsed) s"
