"""RL trainer throughput against the raw speed of the same 8 worker processes; writes
bench/results/rl_throughput.json.

    nice -n 10 .venv/bin/python bench/rl_throughput.py --env-groups 1,2   # Kuka, 96 px, 8 envs, 5 updates
    .venv/bin/python bench/rl_throughput.py --world turtlebot --image-size 64 --updates 3

1. raw: `AsyncVectorEnv` of 8 worlds stepped with random actions (no learner at all);
2. trainer: the full PPO loop with the VAR reward (a randomly initialised VAR of the same shape: the weights
do not change the cost), reported as env steps/s over whole updates, with the time shares (waiting for the
workers, VAR embedding, acting, PPO update). The reference trains at 4.7 env steps/s on this kind of machine.
Other agents may be loading the CPU: the load average is recorded beside the figures.
"""

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results"
REFERENCE_SPS = 4.7


def raw_speed(world: str, num_envs: int, image_size: int, steps: int) -> float:
    from learning.rl.envs import make_vector_env, world_id

    envs = make_vector_env(world_id(world), num_envs, image_size)
    try:
        envs.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(10):  # warm-up
            envs.step(rng.uniform(-1, 1, (num_envs, 2)).astype(np.float32))
        start = time.perf_counter()
        for _ in range(steps):
            envs.step(rng.uniform(-1, 1, (num_envs, 2)).astype(np.float32))
        return steps * num_envs / (time.perf_counter() - start)
    finally:
        envs.close()


def trainer_speed(
    world: str, num_envs: int, image_size: int, updates: int, policy_image_size: int, env_groups: int
) -> dict:
    import numpy as np

    from learning.rl.ppo import PPOConfig, PPOTrainer
    from learning.rl.rewards import ClipBank
    from learning.var.model import VAR, VARConfig

    var = VAR(VARConfig(image_size=image_size)).eval()
    rng = np.random.default_rng(0)
    goals = ClipBank(rng.normal(size=(8, 100, 40)).astype(np.float32), np.arange(8) % 4)
    config = PPOConfig(
        world=world,
        image_size=image_size,
        policy_image_size=policy_image_size,
        num_envs=num_envs,
        env_groups=env_groups,
        total_steps=(updates + 1) * num_envs * 100,
        checkpoint_every=10_000,
    )
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = PPOTrainer(config, Path(run_dir), var, goals)
        try:
            trainer.start()
            trainer._reset_envs()
            trainer.run_one_update()  # warm-up: first allocations, first episodes
            from learning.rl.ppo import Timings

            trainer.timings = Timings()
            start = time.perf_counter()
            for _ in range(updates):
                trainer.run_one_update()
            elapsed = time.perf_counter() - start
        finally:
            trainer.close()
    steps = updates * config.batch_size
    return {
        "steps_per_s": steps / elapsed,
        "seconds_per_update": elapsed / updates,
        "batch": config.batch_size,
        "time_shares": trainer.timings.shares(),
        "peak_memory_mb": trainer.peak_memory_bytes / 2**20,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", default="kuka")
    parser.add_argument("--image-size", type=int, default=96)
    parser.add_argument("--policy-image-size", type=int, default=32)
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--updates", type=int, default=5)
    parser.add_argument("--raw-steps", type=int, default=150, help="vector steps for the raw measurement")
    parser.add_argument(
        "--env-groups", default="2", help="comma-separated: 1 = lockstep, 2 = two groups in turn"
    )
    args = parser.parse_args()

    load_start = os.getloadavg()
    # raw speed before and after the trainer runs: the machine is shared, so the load drifts
    raw_before = raw_speed(args.world, args.envs, args.image_size, args.raw_steps)
    trainers = {}
    for groups in [int(g) for g in args.env_groups.split(",")]:
        trainers[groups] = trainer_speed(
            args.world, args.envs, args.image_size, args.updates, args.policy_image_size, groups
        )
    raw_after = raw_speed(args.world, args.envs, args.image_size, args.raw_steps)
    raw = (raw_before + raw_after) / 2
    load_end = os.getloadavg()
    best = max(trainers.values(), key=lambda t: t["steps_per_s"])
    result = {
        "benchmark": "rl_throughput",
        "world": args.world,
        "image_size": args.image_size,
        "policy_image_size": args.policy_image_size,
        "num_envs": args.envs,
        "raw_env_steps_per_s": raw,
        "raw_before_after": [raw_before, raw_after],
        "trainer_by_env_groups": trainers,
        "trainer_steps_per_s": best["steps_per_s"],
        "ratio_to_raw": best["steps_per_s"] / raw,
        "speedup_over_reference": best["steps_per_s"] / REFERENCE_SPS,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "load_average": {"start": load_start, "end": load_end},
        "note": "2-core machine shared with other agents; load average recorded",
    }
    table = Table(title=f"RL throughput: {args.world}, {args.image_size} px, {args.envs} envs")
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("raw env steps/s (random actions, before / after)", f"{raw_before:.1f} / {raw_after:.1f}")
    for groups, trainer in trainers.items():
        label = "lockstep" if groups == 1 else f"{groups} groups in turn"
        table.add_row(f"trainer env steps/s ({label})", f"{trainer['steps_per_s']:.1f}")
        table.add_row("  trainer / raw", f"{trainer['steps_per_s'] / raw:.2f}")
        table.add_row("  seconds per 800-step update", f"{trainer['seconds_per_update']:.2f}")
        for part, share in trainer["time_shares"].items():
            table.add_row(f"  share {part.removesuffix('_s')}", f"{share:.1%}")
        table.add_row("  peak memory (PSS, learner + workers)", f"{trainer['peak_memory_mb']:.0f} MB")
    table.add_row("best × reference (4.7 steps/s)", f"{result['speedup_over_reference']:.0f}")
    table.add_row("load average start / end", f"{load_start[0]:.1f} / {load_end[0]:.1f}")
    Console().print(table)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "rl_throughput.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
