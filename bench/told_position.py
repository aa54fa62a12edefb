"""Does a base policy steer by the position it is told? (issue 25: why a moved camera costs it points)

The policy sees its view and M_t, the gripper's (x, y) (or a TurtleBot's odometry). A policy that read the
block's place off fixed pixels and drove M_t there would miss by the offset when M_t is told wrong; one that
brings the gripper and the block together in its view would not care. This evaluates a base model in one room
with the RL protocol (`learning.rl.evaluate`, deterministic, unheard goal clips) once per offset, the world
unchanged, only the position handed to the policy shifted by (dx, dy) metres.
Prints a table and writes bench/results/told_position.json with the load average it ran under.

    nice -n 5 .venv/bin/python bench/told_position.py [--base worker/base_models/kuka]
        [--offsets 0/0,0.03/0,0/0.03] [--room training] [--split unheard-easy] [--episodes-per-intent 20]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conditions import measure_and_publish
from result_files import relative_path
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results" / "told_position.json"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", default="kuka")
    parser.add_argument("--base", type=Path, default=None, help="base model folder (default: find_base)")
    parser.add_argument("--offsets", default="0/0,0.03/0,0/0.03", help="dx/dy in metres, comma-separated")
    parser.add_argument("--room", default="training")
    parser.add_argument("--split", default="unheard-easy")
    parser.add_argument("--episodes-per-intent", type=int, default=20)
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def offsets(text: str) -> list[tuple[float, float]]:
    pairs = [part.split("/") for part in text.split(",") if part]
    if any(len(pair) != 2 for pair in pairs):
        raise SystemExit(f"--offsets takes dx/dy pairs in metres, e.g. 0/0,0.03/0; got {text!r}")
    return [(float(dx), float(dy)) for dx, dy in pairs]


def told_off_by(policy, dx: float, dy: float) -> None:  # type: ignore[no-untyped-def]
    """From now on `policy.step` hands the network M_t with (dx, dy) added to its first two numbers."""
    import torch

    step, shift = policy.step, torch.tensor([dx, dy])

    def shifted_step(images, var_embedding, state, *rest):  # type: ignore[no-untyped-def]
        state = state.clone()
        state[:, :2] += shift
        return step(images, var_embedding, state, *rest)

    policy.step = shifted_step


def measure(args: argparse.Namespace) -> dict:
    import torch

    from core.rooms import world_room
    from learning.rl.evaluate import evaluate
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank
    from learning.var.checkpoint import load_var
    from worker.base_models import BaseModel, find_base

    base = BaseModel(args.world, args.base) if args.base else find_base(args.world)
    var = load_var(base.var_path)
    torch.set_num_threads(1)  # the env workers come from a fork server, which torch's threads never reach
    config = PPOConfig.from_dict(load_policy(base.policy_path)[1]["config"])
    goals = corpus_bank(config.sounds, args.split, front_end=var.front_end).embed(var)
    rows = []
    for dx, dy in offsets(args.offsets):
        policy = load_policy(base.policy_path)[0]  # a fresh copy: `told_off_by` wraps its step for good
        told_off_by(policy, dx, dy)
        tick = time.perf_counter()
        result = evaluate(
            policy, var, goals, config.world, config.image_size, split=args.split,
            episodes_per_intent=args.episodes_per_intent, seed=args.seed, success_rule=config.success_rule,
            max_steps=config.max_episode_steps, domain=world_room(args.room), progress=True,
        )  # fmt: skip
        rows.append({
            "offset_m": [dx, dy],
            "success_rate": result.success_rate,
            "success_by_intent": result.success_by_intent,
            "final_view_by_intent": result.final_view_by_intent,
            "median_final_distance_m": round(statistics.median(e.final_distance for e in result.episodes), 4),
            "episodes": len(result.episodes),
            "wall_s": round(time.perf_counter() - tick, 1),
        })  # fmt: skip
    return {"base": relative_path(base.folder), "room": args.room, "split": args.split, "seed": args.seed,
            "episodes_per_intent": args.episodes_per_intent, "rows": rows}  # fmt: skip


def table(result: dict) -> Table:
    view = Table(title=f"{result['base']} in {result['room']} ({result['split']}), told its position off by")
    for column in ("dx, dy (m)", "success", "median final distance", "ended at a wrong block"):
        view.add_column(column, justify="right")
    for row in result["rows"]:
        ended = row["final_view_by_intent"]
        wrong = sum(sum(r[:4]) - r[goal] for goal, r in enumerate(ended))
        dx, dy = row["offset_m"]
        distance = f"{row['median_final_distance_m'] * 100:.1f} cm"
        view.add_row(
            f"{dx:+.3f}, {dy:+.3f}", f"{row['success_rate']:.1%}", distance, f"{wrong} of {row['episodes']}"
        )
    return view


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    measure_and_publish("told_position", lambda: measure(args), table, args.out, argv)


if __name__ == "__main__":
    main()
