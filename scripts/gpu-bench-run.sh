#!/bin/bash
# Runs on a lent GPU machine, from the repository root, after scripts/gpu-bench-prepare.sh here:
#     device run, carry [".dev"], command "bash scripts/gpu-bench-run.sh"
# Builds pybullet 3.2.7 for the machine's Python 3.12 (44 s on 16 cores), then measures the RL trainer with
# its VAR and policy on the GPU (bench/rl_throughput.py --device cuda, 8 and 14 envs) and on that machine's
# CPU; the results files come back under $OUT.
set -u
export PYTHONUNBUFFERED=1
source scripts/gpu-pybullet.sh
timeout $(( 560 - $(elapsed) )) python3 bench/rl_throughput.py --device cuda --env-groups 1,2 --updates 10 \
    --results rl_throughput_gpu.json; echo "8 envs rc=$? at $(elapsed) s"
cp bench/results/rl_throughput_gpu.json "$OUT/" 2>/dev/null
left=$(( 570 - $(elapsed) ))
if [ $left -gt 90 ]; then
  timeout $left python3 bench/rl_throughput.py --device cuda --envs 14 --env-groups 1,2 --updates 10 \
      --results rl_throughput_gpu_14envs.json; echo "14 envs rc=$? at $(elapsed) s"
  cp bench/results/rl_throughput_gpu_14envs.json "$OUT/" 2>/dev/null
fi
left=$(( 590 - $(elapsed) ))
if [ $left -gt 60 ]; then
  timeout $left python3 bench/rl_throughput.py --device cpu --env-groups 1,2 --updates 10 \
      --results rl_throughput_gpu_machine_cpu.json; echo "cpu rc=$? at $(elapsed) s"
  cp bench/results/rl_throughput_gpu_machine_cpu.json "$OUT/" 2>/dev/null
fi
echo "done at $(elapsed) s"
