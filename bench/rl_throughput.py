"""RL trainer throughput against the raw speed of the same 8 worker processes; writes
bench/results/rl_throughput.json.

    nice -n 10 .venv/bin/python bench/rl_throughput.py --env-groups 1,2   # Kuka, 96 px, 8 envs, 5 updates
    .venv/bin/python bench/rl_throughput.py --world turtlebot --image-size 64 --updates 3
    python bench/rl_throughput.py --device cuda --results rl_throughput_gpu.json  # on a GPU machine
    .venv/bin/python bench/rl_throughput.py --policy-view var --results rl_throughput_var_view.json

1. raw: `AsyncVectorEnv` of 8 worlds stepped with random actions (no learner at all), measured by
bench/raw_stepping.py exactly as bench/env_speed.py measures it;
2. trainer: the full PPO loop with the VAR reward (a randomly initialised VAR of the same shape: the weights
do not change the cost), reported as env steps/s over whole updates, with the time shares (waiting for the
workers, VAR embedding, acting, PPO update), and the CPU ms per env step of the learner and its workers.
Two ratios: wall (trainer steps/s over raw steps/s, raw measured before and after) and CPU (raw CPU per
step over the trainer's): on a shared machine the wall figures move with other people's load, the CPU ones
do not. The JSON holds the reference implementation's speed (REFERENCE:
its value, unit and source) beside the ratio to it, and the machine and the load average before and after.
Earlier runs stay in the file under earlier_runs, each with its own load: compare runs only at a similar load.
--device (auto, cpu, cuda: what VARBOT_DEVICE means to a worker) says where the trainer's VAR and policy run;
on a machine with enough cores the trainer gives each environment worker a core of its own
(`learning.device.core_plan`). --results names the file in bench/results, so that another machine's figures
do not mix with this one's.
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from conditions import Conditions, describe
from raw_stepping import DEFAULT_STEPS, CpuClock, raw_stepping, speed_figures, vector_workers
from result_files import write_result
from rich.console import Console
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results"
REFERENCE = {  # cited, not measured here
    "value": 4.7,
    "unit": "env steps/s",
    "what": "PPO training speed of the public reference implementation of the paper (8 envs, VAR reward)",
    "measured_on": "a 2-core machine like this one: 2 CPU cores, torch 2.11 on the CPU, espeak-ng voices",
    "source": "the project's design brief (../shared/DESIGN.md beside the checkout): 'its PPO runs at "
    "4.7 env steps/s because each 800-step update takes about 154 s (91 % of the time)'",
}


def raw_speed(world: str, num_envs: int, image_size: int, steps: int) -> dict[str, float]:
    """bench/raw_stepping.py, the same measurement bench/env_speed.py reports."""
    return raw_stepping(world, num_envs, image_size, steps)


def trainer_speed(
    world: str,
    num_envs: int,
    image_size: int,
    updates: int,
    policy_image_size: int,
    env_groups: int,
    device: str,
    policy_view: str = "pixels",
    torch_threads: int = 1,
) -> dict:
    from learning.device import resolve_device
    from learning.rl.frozen_var import LoadedVar
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
        policy_view=policy_view,
        torch_threads=torch_threads,
        total_steps=(updates + 1) * num_envs * 100,
        checkpoint_every=10_000,
    )
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = PPOTrainer(
            config, Path(run_dir), LoadedVar.in_memory(var), goals, device=resolve_device(device)
        )
        try:
            trainer.start()
            trainer.reset_envs()
            trainer.run_one_update()  # warm-up: first allocations, first episodes
            from learning.rl.ppo import Timings

            trainer.timings = Timings()
            clock = CpuClock(worker for envs in trainer.envs.vector_envs for worker in vector_workers(envs))
            clock.start()
            for _ in range(updates):
                trainer.run_one_update()
            clock.stop()
        finally:
            trainer.close()
    return {
        **speed_figures(updates * config.batch_size, clock),
        "seconds_per_update": clock.wall_s / updates,
        "batch": config.batch_size,
        "time_shares": trainer.timings.shares(),
        "peak_memory_mb": trainer.memory.peak_mb,
    }


def earlier_runs(path: Path) -> list[dict]:
    """The runs the file held before this one, oldest first."""
    if not path.exists():
        return []
    previous = json.loads(path.read_text())
    return [*previous.pop("earlier_runs", []), previous]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", default="kuka")
    parser.add_argument("--image-size", type=int, default=96)
    parser.add_argument("--policy-image-size", type=int, default=32)
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--updates", type=int, default=5)
    parser.add_argument(
        "--raw-steps", type=int, default=DEFAULT_STEPS, help="vector steps for the raw measurement"
    )
    parser.add_argument(
        "--env-groups", default="2", help="comma-separated: 1 = lockstep, 2 = two groups in turn"
    )
    parser.add_argument(
        "--device", default="auto", help="where the trainer's VAR and policy run: auto, cpu or cuda"
    )
    parser.add_argument(
        "--policy-view", default="pixels", choices=("pixels", "var"),
        help="what the policy sees: its own CNN over the view, or the VAR's hidden layer (one f_I pass)",
    )  # fmt: skip
    parser.add_argument(
        "--torch-threads", type=int, default=1, help="the learner's torch threads (PPOConfig.torch_threads)"
    )
    parser.add_argument("--results", default="rl_throughput.json", help="file name in bench/results to write")
    args = parser.parse_args()

    conditions = Conditions()
    # raw speed before and after the trainer runs: the machine is shared, so the load drifts
    raw_before = raw_speed(args.world, args.envs, args.image_size, args.raw_steps)
    trainers = {}
    for groups in [int(g) for g in args.env_groups.split(",")]:
        trainers[groups] = trainer_speed(
            args.world,
            args.envs,
            args.image_size,
            args.updates,
            args.policy_image_size,
            groups,
            args.device,
            args.policy_view,
            args.torch_threads,
        )
    raw_after = raw_speed(args.world, args.envs, args.image_size, args.raw_steps)
    raw = (raw_before["steps_per_s"] + raw_after["steps_per_s"]) / 2
    raw_cpu = (raw_before["cpu_ms_per_step"] + raw_after["cpu_ms_per_step"]) / 2
    for trainer in trainers.values():
        trainer["ratio_to_raw"] = trainer["steps_per_s"] / raw
        # CPU the raw envs need per step over CPU the whole trainer needs: the wall ratio on a machine the
        # bench has to itself, whatever else runs here now
        trainer["cpu_ratio_to_raw"] = raw_cpu / trainer["cpu_ms_per_step"]
    measured = conditions.finish()
    best = max(trainers.values(), key=lambda t: t["steps_per_s"])
    result = {
        "benchmark": "rl_throughput",
        "world": args.world,
        "image_size": args.image_size,
        "policy_image_size": args.policy_image_size,
        "num_envs": args.envs,
        "policy_view": args.policy_view,
        "torch_threads": args.torch_threads,
        "device": args.device,
        "raw_env_steps_per_s": raw,
        "raw_cpu_ms_per_step": raw_cpu,
        "raw_before_after": [raw_before, raw_after],
        "trainer_by_env_groups": trainers,
        "trainer_steps_per_s": best["steps_per_s"],
        "ratio_to_raw": best["ratio_to_raw"],
        "cpu_ratio_to_raw": best["cpu_ratio_to_raw"],
        "reference": REFERENCE,
        "speedup_over_reference": best["steps_per_s"] / REFERENCE["value"],
        **measured,
    }
    table = Table(
        title=f"RL throughput: {args.world}, {args.image_size} px, {args.envs} envs, device {args.device}, "
        f"policy sees {args.policy_view}, {args.torch_threads} learner thread(s)"
    )
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row(
        "raw env steps/s (random actions, before / after)",
        f"{raw_before['steps_per_s']:.1f} / {raw_after['steps_per_s']:.1f}",
    )
    table.add_row("raw CPU ms per env step (all processes)", f"{raw_cpu:.2f}")
    for groups, trainer in trainers.items():
        label = "lockstep" if groups == 1 else f"{groups} groups in turn"
        table.add_row(f"trainer env steps/s ({label})", f"{trainer['steps_per_s']:.1f}")
        table.add_row("  trainer / raw (wall)", f"{trainer['ratio_to_raw']:.2f}")
        table.add_row("  CPU ms per env step (learner + workers)", f"{trainer['cpu_ms_per_step']:.2f}")
        table.add_row("  trainer / raw (CPU)", f"{trainer['cpu_ratio_to_raw']:.2f}")
        table.add_row("  seconds per 800-step update", f"{trainer['seconds_per_update']:.2f}")
        for part, share in trainer["time_shares"].items():
            table.add_row(f"  share {part.removesuffix('_s')}", f"{share:.1%}")
        table.add_row("  peak memory (PSS, learner + workers)", f"{trainer['peak_memory_mb']:.0f} MB")
    reference = f"{REFERENCE['value']} {REFERENCE['unit']}, cited"
    table.add_row(f"best × reference ({reference})", f"{result['speedup_over_reference']:.0f}")
    Console().print(table)
    print(describe(measured))
    output = RESULTS / args.results
    write_result(output, {**result, "earlier_runs": earlier_runs(output)})


if __name__ == "__main__":
    main()
