"""How a TurtleBot policy's failed tries end, and what the arena's contact rule costs it (issue 23).

Replays the evaluation episodes that `bench/reproduce.py` stored for a run (RUN/bench-eval-<tier>.json: layout
seed, command, goal clip) one by one with the policy's deterministic action, as the evaluation protocol plays
them, and follows each try step by step in the simulator: where the robot is, what share of its view shows
its object, how close it is to its object and to everything else. Replayed under the run's own contact rule,
every try must end as the stored one did (the table says how many agree). Each failed try is put in the first
class that fits it:

- at its object, off-centre: it ended within reach of its object (`SUCCESS_CLEARANCE_M`) but not facing it;
- pressed against something else: it stood still for its last `STILL_STEPS` steps, touching another object
  or a wall (the "stop" rule drops a blocked move, so a robot driving on into an obstacle stays put);
- stopped short of its object: it stood still for its last `STILL_STEPS` steps facing its object (within the
  success bearing), beyond reach but within the world's default heard reach (`HEARD_MAX_CLEARANCE_M`, 0.6 m,
  where the default VAR's training views name it; a VAR made with `--var-heard-reach` names views only closer,
  so for its runs this class is a fixed distance band, not its own reach);
- never saw its object: not one pixel of it in any view;
- elsewhere: anything else (it saw its object and ended away from it, still moving).

--contacts stop,slide replays the same tries in both arenas with the same policy: the "slide" figure is what
the policy reaches when a blocked robot glides along what it meets (sim.turtlebot_arena), without training.
Ground truth is read here only, to describe tries; nothing feeds back into training.
Prints a table and writes bench/results/blocked_tries.json with the load average it ran under.

    VARBOT_DATA_DIR=… nice -n 10 .venv/bin/python bench/blocked_tries.py RUN_DIR [RUN_DIR …] \\
        [--split unheard-easy] [--contacts stop,slide]
"""

import argparse
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conditions import measure_and_publish
from result_files import relative_path
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results" / "blocked_tries.json"
STILL_STEPS = 20  # a try that has not moved for this many steps at its end has stopped for good
# "not moved": every position of those steps within 1 cm of the last (a standing policy creeps)
STILL_M = 0.01
TOUCHING_M = 0.02  # within one integration slice (1.25 cm) of an obstacle, with margin
ENDINGS = (
    "at its object, off-centre",
    "pressed against something else",
    "stopped short of its object",
    "never saw its object",
    "elsewhere",
)
SHORT_NAMES = ("off-centre", "pressed", "stopped short", "never saw", "elsewhere")  # the table's headings


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", type=Path, nargs="+", help="run directories written by bench/reproduce.py")
    parser.add_argument("--split", default="unheard-easy")
    parser.add_argument("--contacts", default="stop,slide", help="rules to replay under, comma-separated")
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def classify(steps: list[dict[str, Any]], success: bool) -> str | None:
    """How a try ended (one of ENDINGS), or None for a success. `steps`: one dict per step after it, with the
    robot's xy, its object's pixel share, clearance and bearing, and its clearance to everything else."""
    from sim.turtlebot_arena import HEARD_MAX_CLEARANCE_M, SUCCESS_BEARING_DEG, SUCCESS_CLEARANCE_M

    if success:
        return None
    last = steps[-1]
    within_reach = last["target_clearance_m"] <= SUCCESS_CLEARANCE_M
    if within_reach and abs(last["target_bearing_deg"]) > SUCCESS_BEARING_DEG:
        return ENDINGS[0]
    tail = [step["xy"] for step in steps[-STILL_STEPS:]]
    still = len(steps) >= STILL_STEPS and all(math.dist(xy, tail[-1]) < STILL_M for xy in tail)
    if still and last["other_clearance_m"] < TOUCHING_M:
        return ENDINGS[1]
    facing = abs(last["target_bearing_deg"]) <= SUCCESS_BEARING_DEG
    if still and facing and last["target_clearance_m"] <= HEARD_MAX_CLEARANCE_M:
        return ENDINGS[2]
    if not any(step["target_share"] > 0.0 for step in steps):
        return ENDINGS[3]
    return ENDINGS[4]


def where_the_try_is(env: Any, obs: dict, target: int) -> dict[str, Any]:
    """One step of a try as `classify` reads it (ground truth from the simulator)."""
    from sim.turtlebot_arena import ROBOT_RADIUS_M, wall_clearance

    xy = obs["state"][:2].astype(float)
    others = [k for k in range(env.num_intents) if k != target]
    walls = float(wall_clearance(xy)[0]) - ROBOT_RADIUS_M
    return {
        "xy": xy.tolist(),
        "target_share": env.object_pixel_shares()[target],
        "target_clearance_m": env.object_clearance(target),
        "target_bearing_deg": math.degrees(env.object_bearing(target)),
        "other_clearance_m": min(walls, *(env.object_clearance(k) for k in others)),
    }


def replay(run: Path, split: str, contact: str) -> dict[str, Any]:
    """Every stored evaluation episode of `run` again, under `contact`; its success and how it ended."""
    import numpy as np
    import torch
    from tqdm.auto import tqdm

    from learning.rl.evaluate import encode_views, goal_inputs
    from learning.rl.frozen_var import load_frozen_var
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank
    from sim.turtlebot_arena import TurtleBotArenaEnv

    torch.set_num_threads(1)
    saved = json.loads((run / "config.json").read_text())
    config = PPOConfig.from_dict(saved)
    if config.world != "turtlebot":
        raise SystemExit(f"{run} is a {config.world} run; this bench replays TurtleBot runs")
    stored = json.loads((run / f"bench-eval-{split}.json").read_text())["episodes"]
    policy = load_policy(run / "checkpoint.pt")[0].eval()
    var = load_frozen_var(Path(saved["var_path"])).model if saved.get("var_path") else None
    goals = corpus_bank(config.sounds, split, front_end=var.front_end if var is not None else "mfcc")
    if var is not None:
        goals.embed(var)
    env = TurtleBotArenaEnv(image_size=config.image_size, contact=contact)
    tries = []
    try:
        for episode in tqdm(stored, desc=f"{run.name} {split} {contact}", unit="try"):
            obs, _ = env.reset(seed=episode["seed"], options={"intent": episode["intent"]})
            target = episode["intent"]
            hidden, start, steps, info = policy.initial_state(1), torch.ones(1), [], {}
            with torch.inference_mode():
                clip = np.array([episode["goal_clip"]])
                goal = policy.encode_goal(goal_inputs(goals, clip, config.goal_encoder))
                for _ in range(env.max_steps):
                    image = torch.from_numpy(obs["image"][None])
                    state = torch.from_numpy(obs["state"][None].astype(np.float32))
                    seen = encode_views(var, obs["image"][None], policy.config.var_dim)
                    mean, _, hidden = policy.step(policy.view_of(image), seen, state, goal, hidden, start)
                    start = torch.zeros(1)
                    obs, _, _, _, info = env.step(mean.clamp(-1.0, 1.0).numpy()[0])
                    steps.append(where_the_try_is(env, obs, target))
            success = bool(info["success"])
            tries.append({"intent": target, "success": success, "stored_success": episode["success"],
                          "ended": classify(steps, success),
                          "final_clearance_m": steps[-1]["target_clearance_m"]})  # fmt: skip
    finally:
        env.close()
    where = {"run": relative_path(run), "split": split, "contact": contact,
             "trained_contact": config.contact or "stop"}  # fmt: skip
    return summarise(tries, env.intent_names) | where


def clearance_range(tries: list[dict[str, Any]], ending: str) -> dict[str, float] | None:
    """Smallest, median and largest final clearance to its object of the tries that ended so (None: none)."""
    ended = [t["final_clearance_m"] for t in tries if t["ended"] == ending]
    if not ended:
        return None
    summary = {"min": min(ended), "median": statistics.median(ended), "max": max(ended)}
    return {name: round(value, 3) for name, value in summary.items()}


def summarise(tries: list[dict[str, Any]], names: list[str]) -> dict[str, Any]:
    by_intent = {
        name: {
            "tries": sum(t["intent"] == k for t in tries),
            "success": sum(t["success"] for t in tries if t["intent"] == k),
            **{ending: sum(t["ended"] == ending for t in tries if t["intent"] == k) for ending in ENDINGS},
        }
        for k, name in enumerate(names)
    }
    return {
        "tries": len(tries),
        "success_rate": sum(t["success"] for t in tries) / len(tries),
        "agrees_with_stored": sum(t["success"] == t["stored_success"] for t in tries),
        "failed_by_ending": {ending: sum(t["ended"] == ending for t in tries) for ending in ENDINGS},
        # how far from its object the robot ended, over the failed tries of each ending
        "final_clearance_m_by_ending": {ending: clearance_range(tries, ending) for ending in ENDINGS},
        "by_intent": by_intent,
    }


def measure(args: argparse.Namespace) -> dict:
    contacts = [c for c in args.contacts.split(",") if c]
    cells = [replay(run.resolve(), args.split, contact) for run in args.runs for contact in contacts]
    return {"split": args.split, "still_steps": STILL_STEPS, "still_m": STILL_M, "touching_m": TOUCHING_M,
            "cells": cells}  # fmt: skip


def table(result: dict) -> Table:
    view = Table(title=f"TurtleBot tries replayed ({result['split']}): success, how the failed ones ended")
    for column in ("run", "contact: trained / replayed", "success", "as stored", *SHORT_NAMES):
        view.add_column(column, justify="right")
    for cell in result["cells"]:
        ended = cell["failed_by_ending"]
        view.add_row(
            Path(cell["run"]).parent.name,
            f"{cell['trained_contact']} / {cell['contact']}",
            f"{cell['success_rate']:.1%}",
            f"{cell['agrees_with_stored']} of {cell['tries']}",
            *(str(ended.get(ending, "–")) for ending in ENDINGS),  # "–": measured before that class existed
        )
    return view


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    measure_and_publish("blocked_tries", lambda: measure(args), table, args.out, argv)


if __name__ == "__main__":
    main()
