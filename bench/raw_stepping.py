"""Raw vector-env stepping, measured one way for every bench that cites it (bench/env_speed.py,
bench/rl_throughput.py): the trainer's own environments (`learning.rl.envs.make_vector_env`: SAME_STEP
autoreset, `RLInfo`), random actions, a warm-up, then a window that includes episode resets as training does.

Two figures: wall-clock env steps/s, which is the share of the machine the bench got (on a shared machine it
moves with other people's load), and CPU milliseconds per env step summed over this process and its workers,
which does not. Two measurements of the same envs agree on the second and may differ on the first.
"""

import time
from collections.abc import Iterable
from typing import Any

import numpy as np
import psutil

DEFAULT_STEPS = 150  # per env: past one episode end (100 steps), so resets are in the window
WARMUP_STEPS = 10


def cpu_seconds(processes: Iterable[psutil.Process]) -> float:
    """User + system CPU seconds of `processes` (a process that already exited counts 0)."""
    total = 0.0
    for process in processes:
        try:
            times = process.cpu_times()
        except psutil.Error:
            continue
        total += times.user + times.system
    return total


class CpuClock:
    """CPU seconds of this process and `workers` between `start()` and `stop()`, beside the wall time."""

    def __init__(self, workers: Iterable[psutil.Process]) -> None:
        self.processes = [psutil.Process(), *workers]
        self.cpu_s = 0.0
        self.wall_s = 0.0

    def start(self) -> None:
        self._cpu = cpu_seconds(self.processes)
        self._wall = time.perf_counter()

    def stop(self) -> None:
        self.cpu_s += cpu_seconds(self.processes) - self._cpu
        self.wall_s += time.perf_counter() - self._wall


def vector_workers(envs: Any) -> list[psutil.Process]:
    return [psutil.Process(process.pid) for process in getattr(envs, "processes", ())]


def speed_figures(env_steps: int, clock: CpuClock) -> dict[str, float]:
    return {
        "steps_per_s": env_steps / clock.wall_s,
        "cpu_ms_per_step": 1000 * clock.cpu_s / env_steps,
        "wall_s": clock.wall_s,
    }


def raw_stepping(
    world: str,
    num_envs: int,
    image_size: int,
    steps: int = DEFAULT_STEPS,
    warmup: int = WARMUP_STEPS,
    **world_options: Any,
) -> dict[str, float]:
    """Steps `num_envs` envs of `world` with random actions: steps_per_s, cpu_ms_per_step, wall_s and the
    workers' mean RSS (rss_mb_per_env)."""
    from learning.rl.envs import make_vector_env, world_id

    envs = make_vector_env(world_id(world), num_envs, image_size, world_options=world_options)
    try:
        rng = np.random.default_rng(0)
        envs.reset(seed=0)
        for _ in range(warmup):
            envs.step(rng.uniform(-1, 1, (num_envs, 2)).astype(np.float32))
        workers = vector_workers(envs)
        clock = CpuClock(workers)
        clock.start()
        for _ in range(steps):
            envs.step(rng.uniform(-1, 1, (num_envs, 2)).astype(np.float32))
        clock.stop()
        rss = [worker.memory_info().rss / 2**20 for worker in workers]
    finally:
        envs.close()
    return {**speed_figures(steps * num_envs, clock), "rss_mb_per_env": float(np.mean(rss))}
