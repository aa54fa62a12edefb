"""Environment speed: steps/s of every world at 64, 96 and 128 px, alone and as 8 worker processes.

The 8-process figure is bench/raw_stepping.py's, the one bench/rl_throughput.py compares the trainer with:
wall steps/s (the machine's share this bench got) and CPU ms per env step (which the load does not move).

Also: the share of a step spent rendering (time inside PyBullet's getCameraImage), the memory (RSS) of each
worker process, and for the Kuka the full-detail reference arm next to the default simplified visual model,
with how many pixels the two differ in. Prints a table and writes bench/results/env_speed.json (a --quick run
writes env_speed_quick.json, so it never replaces the full measurement).

    .venv/bin/python bench/env_speed.py [--quick]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pybullet
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import gymnasium as gym
from conditions import Conditions, describe
from raw_stepping import DEFAULT_STEPS, raw_stepping
from result_files import write_result

import sim

RESULTS = Path(__file__).resolve().parent / "results"
NUM_ENVS = 8


class RenderClock:
    """Counts the time spent in pybullet.getCameraImage (every BulletClient call goes through the module)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._original = pybullet.getCameraImage

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return self._original(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start

        pybullet.getCameraImage = timed


def single_process(world: str, size: int, steps: int, clock: RenderClock, **env_kwargs) -> dict:
    env = gym.make(sim.WORLDS[world], image_size=size, **env_kwargs)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    clock.seconds = 0.0
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    render_share = clock.seconds / elapsed
    env.close()
    return {"steps_per_s": steps / elapsed, "step_ms": 1000 * elapsed / steps, "render_share": render_share}


def vectorised(world: str, size: int, steps: int, **env_kwargs) -> dict:
    """The same measurement as bench/rl_throughput.py's raw stepping (bench/raw_stepping.py)."""
    return raw_stepping(world, NUM_ENVS, size, steps, **env_kwargs)


def fast_versus_full_pixels(frames: int = 10) -> float:
    """Share of pixels that differ by more than 32 levels between the simplified and the full Kuka arm."""
    fast = gym.make(sim.KUKA_BLOCKS, image_size=96)
    full = gym.make(sim.KUKA_BLOCKS, image_size=96, visual_detail="full")
    shares = []
    for seed in range(frames):
        a, b = fast.reset(seed=seed)[0]["image"], full.reset(seed=seed)[0]["image"]
        shares.append(float((np.abs(a.astype(int) - b).max(axis=2) > 32).mean()))
    fast.close()
    full.close()
    return float(np.mean(shares))


def available_worlds(console: Console) -> list[str]:
    worlds = []
    for world, env_id in sim.WORLDS.items():
        try:
            gym.make(env_id, image_size=32).close()
            worlds.append(world)
        except Exception as error:  # a world another helper has not finished yet
            console.print(f"[yellow]skipping {world}: {type(error).__name__}: {error}")
    return worlds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="96 px only and fewer steps (about a minute)")
    args = parser.parse_args()
    sizes = [96] if args.quick else [64, 96, 128]
    single_steps, vector_steps = (60, DEFAULT_STEPS) if args.quick else (300, DEFAULT_STEPS)
    console = Console()
    clock = RenderClock()
    conditions = Conditions()

    configs = [(world, size, {}) for world in available_worlds(console) for size in sizes]
    if "kuka" in sim.WORLDS:
        configs.append(("kuka", 96, {"visual_detail": "full"}))
    rows = []
    for world, size, extra in configs:
        label = world + (" (full-detail arm)" if extra else "")
        console.print(f"measuring {label} at {size} px …")
        rows.append(
            {
                "world": world,
                "variant": "full-detail arm" if extra else "default",
                "image_size": size,
                "single": single_process(world, size, single_steps, clock, **extra),
                "vector": vectorised(world, size, vector_steps, **extra),
            }
        )
    pixels = fast_versus_full_pixels(3 if args.quick else 10)

    measured = conditions.finish()
    table = Table(title="env steps/s")
    columns = ("world", "px", "1 process", "step ms", "render share", f"{NUM_ENVS} processes", "CPU ms/step")
    for column in (*columns, "RSS/env"):
        table.add_column(column, justify="left" if column == "world" else "right")
    for row in rows:
        table.add_row(
            f"{row['world']} ({row['variant']})" if row["variant"] != "default" else row["world"],
            str(row["image_size"]),
            f"{row['single']['steps_per_s']:.0f}",
            f"{row['single']['step_ms']:.2f}",
            f"{100 * row['single']['render_share']:.0f} %",
            f"{row['vector']['steps_per_s']:.0f}",
            f"{row['vector']['cpu_ms_per_step']:.2f}",
            f"{row['vector']['rss_mb_per_env']:.0f} MB",
        )
    console.print(table)
    console.print(
        f"simplified vs full Kuka arm: {100 * pixels:.2f} % of pixels differ by more than 32 levels"
    )
    console.print(describe(measured))
    out = RESULTS / ("env_speed_quick.json" if args.quick else "env_speed.json")
    write_result(
        out,
        {
            "benchmark": "env_speed",
            "quick": args.quick,
            **measured,
            "num_envs": NUM_ENVS,
            "steps": {"single": single_steps, "vector_per_env": vector_steps},
            "results": rows,
            "kuka_fast_vs_full_pixels_over_32_levels": pixels,
            "note": "compare runs only at a similar load average",
        },
    )
    console.print(f"wrote {out}")


if __name__ == "__main__":
    main()
