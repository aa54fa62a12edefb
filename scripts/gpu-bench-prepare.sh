#!/bin/bash
# Prepares .dev/ (git-ignored) for scripts/gpu-bench-run.sh on a lent GPU machine whose Python (3.12) has
# torch but no pybullet, gymnasium or package registry: pybullet 3.2.7's source (no 3.12 wheel exists) cut
# to what the build and the Kuka world need, and the pure-Python wheels of gymnasium.
set -euo pipefail
cd "$(dirname "$0")/.."
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")" .dev/whl
grep -qx "/.dev/" "$exclude" 2>/dev/null || echo "/.dev/" >>"$exclude"
work=$(mktemp -d)
python3 -m pip download -q --no-deps --no-binary=:all: -d "$work" pybullet==3.2.7
tar xzf "$work"/pybullet-3.2.7.tar.gz -C "$work"
source=$work/pybullet-3.2.7
# the EGL renderer plugin is a second long build that a headless tiny-renderer run never loads
sed -i 's/^  extensions.append(eglRender)/  pass  # varbot: no EGL plugin/' "$source/setup.py"
gym=$source/examples/pybullet/gym
rm -rf "$gym"/pybullet_envs "$gym"/pybullet_examples "$gym"/pybullet_robots "$gym"/pybullet.egg-info
find "$gym/pybullet_data" -mindepth 1 -maxdepth 1 ! -name kuka_iiwa ! -name table ! -name __init__.py \
    -exec rm -rf {} +
tar czf .dev/pybullet-3.2.7-trimmed.tar.gz -C "$work" pybullet-3.2.7
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_17_x86_64 -d .dev/whl gymnasium==1.4.0 farama-notifications==0.0.6
rm -rf "$work"
du -sh .dev
