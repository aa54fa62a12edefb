#!/bin/bash
# Runs on a lent GPU machine, from the repository root, after scripts/gpu-bench-prepare.sh here:
#     device run, carry [".dev"], command "bash .dev/gpu-bench-run.sh"
# Builds pybullet 3.2.7 for the machine's Python 3.12 (44 s on 16 cores), then measures the RL trainer with
# its VAR and policy on the GPU (bench/rl_throughput.py --device cuda, 8 and 14 envs) and on that machine's
# CPU; the results files come back under $OUT.
set -u
export PYTHONUNBUFFERED=1
START=$(date +%s)
elapsed() { echo $(( $(date +%s) - START )); }
REPO=$PWD
nvidia-smi -L; python3 --version; nproc; free -g | head -2
PYINC=$(python3 -c "import sysconfig; print(sysconfig.get_paths()['include'])")
ls "$PYINC/Python.h" || { echo "no Python headers at $PYINC"; exit 3; }
which gcc g++ || exit 4
if ! ls /tmp/site/pybullet.*.so; then
mkdir -p /tmp/b /tmp/whl && tar xzf .dev/pybullet-3.2.7-trimmed.tar.gz -C /tmp/b
(cd /tmp/b/pybullet-3.2.7 && timeout 360 python3 -m pip wheel -q --no-build-isolation --no-deps -w /tmp/whl . \
    > "$OUT/build.log" 2>&1); echo "build rc=$? at $(elapsed) s"
ls -la /tmp/whl
python3 -m pip install -q --no-index --no-deps --target /tmp/site /tmp/whl/pybullet-*.whl .dev/whl/*.whl || exit 5
fi
# this pybullet build crashes when it is loaded before torch (seen: 'import pybullet; import torch' segfaults,
# the other order works): every interpreter here, the env workers too, loads torch first
echo "import torch" > /tmp/site/sitecustomize.py
export PYTHONPATH=/tmp/site:$REPO:$REPO/bench
python3 -c "import pybullet, pybullet_data, gymnasium, torch; print(pybullet_data.getDataPath(), torch.cuda.get_device_name())" || exit 6
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
