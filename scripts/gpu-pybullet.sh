#!/bin/bash
# Sourced by the scripts that run on a lent GPU machine (Python 3.12, torch, no registry), from the repository
# root, after scripts/gpu-bench-prepare.sh here: builds pybullet 3.2.7 from .dev/ (44 s on 16 cores),
# installs it with the carried wheels under /tmp/site and points PYTHONPATH there. Defines `elapsed`.
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
