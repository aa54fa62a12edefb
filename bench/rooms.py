"""Zero-shot success of a base model in the training room and in both held-out rooms (issue 25, item 1).

A base model (a world's VAR + policy, `worker/base_models.py`) is evaluated with the RL protocol
(`learning.rl.evaluate`: fixed episode list, deterministic policy, unheard goal clips) in each room of
`--rooms` (default: training, unseen_room, lamplit_room; `core.rooms`) and each unheard tier of `--splits`.
Nothing is fine-tuned: this is what a new household's robot does on its first day in a room it never saw.
Prints a table and writes bench/results/rooms.json, one entry per `--tag` ("before": today's shipped base;
"after": the randomised-room base), with the machine and the load average before and after.

`--env-speed` measures instead what drawing a room per episode costs each world: episodes in the fixed
training room and in randomised rooms, interleaved (so both meet the same load), ms per step and per reset
(bench/results/rooms_env_speed.json).

    nice -n 10 .venv/bin/python bench/rooms.py --tag before [--base worker/base_models/kuka]
        [--episodes-per-intent 50] [--rooms training,unseen_room,lamplit_room]
        [--rooms 'lamplit_room,lamplit_room[camera_jitter_m=0,camera_jitter_deg=0]']  # which knob costs most
        [--rooms 'unseen_room[floor_texture=none],unseen_room[object_rgb=none]']  # none: the world's own look
    nice -n 10 .venv/bin/python bench/rooms.py --tag room-adapted --adapt-views 400 [--adapt-share 0.5]
        # each room's cells from the base adapted to 400 random views of that room (POST …:adapt-to-room)
        [--household-voices 0]  # goal clips: bench/household.py's synthesised family of seed 0, not the tier
    nice -n 10 .venv/bin/python bench/rooms.py --env-speed [--rounds 4]
"""

import argparse
import json
import re
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conditions import Conditions, describe
from result_files import relative_path, write_result
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from core.rooms import HELD_OUT_ROOMS, TRAINING_ROOM, RoomRanges
from worker.base_models import BaseModel

if TYPE_CHECKING:
    from learning.rl.rewards import ClipBank

RESULTS = Path(__file__).resolve().parent / "results" / "rooms.json"
SPEED_RESULTS = RESULTS.with_name("rooms_env_speed.json")
ROOM_KINDS = {"training": None, "randomised": RoomRanges()}
ROOMS = (TRAINING_ROOM, *HELD_OUT_ROOMS)
SPLITS = ("unheard-easy", "unheard-real-voices")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", default="kuka")
    parser.add_argument("--base", type=Path, default=None, help="base model folder (default: find_base)")
    parser.add_argument("--tag", help="the entry in rooms.json, e.g. before / after")
    parser.add_argument("--env-speed", action="store_true", help="measure the cost of randomised rooms")
    parser.add_argument("--rounds", type=int, default=4, help="--env-speed: episodes per room kind and world")
    parser.add_argument("--rooms", default=",".join(ROOMS))
    parser.add_argument("--splits", default=",".join(SPLITS))
    parser.add_argument("--episodes-per-intent", type=int, default=50)
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument(
        "--adapt-views", type=int, default=0,
        help="adapt the base to each room first, from this many random views of it (worker.room_adaptation)",
    )  # fmt: skip
    parser.add_argument(
        "--adapt-share", type=float, default=0.5, help="--adapt-views: how far the statistics move"
    )
    parser.add_argument("--adapt-seed", type=int, default=7, help="--adapt-views: the views' seed")
    parser.add_argument(
        "--household-voices", type=int, default=None, metavar="SEED",
        help="goal clips: the household bench's synthesised family of this seed in each tier (its members "
        "and clips a command as bench/household.py's defaults), not the whole tier",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def evaluate_base(args: argparse.Namespace, save: Callable[[dict], None]) -> dict:
    """Success of the base model in every room × tier cell, with what it is; `save` gets the entry after every
    cell (an interrupted run keeps the cells it finished)."""
    from learning.var.checkpoint import front_end_of
    from worker.base_models import evaluate_in_rooms, find_base

    base = BaseModel(args.world, args.base) if args.base else find_base(args.world)
    entry = {
        "base": relative_path(base.folder),
        "base_built_at": base.record.get("built_at"),
        "base_recipe": base.record.get("recipe", "training room only (before issue 25)"),
        # a base whose policy was trained apart from its VAR (`varbot models adopt`) says how
        "base_policy_recipe": base.record.get("policy_recipe"),
        "base_policy_command": base.record.get("policy_command"),
        "front_end": front_end_of(base.var_path),
        "sounds": base.record.get("sounds"),
        "episodes_per_intent": args.episodes_per_intent,
        "seed": args.seed,
        "room_adaptation": (
            {"views": args.adapt_views, "share": args.adapt_share, "views_seed": args.adapt_seed}
            if args.adapt_views
            else None
        ),
        "goal_clips": goal_clips_said(args.household_voices),
        "cells": {},
    }

    def on_cell(room: str, split: str, cell: dict) -> None:
        entry["cells"].setdefault(room, {})[split] = cell
        print(f"{room} / {split}: {cell['success_rate']:.1%} ({cell['episodes']} episodes)", flush=True)
        save(entry)

    for room in room_names(args.rooms):
        var_path, policy_path = base.var_path, base.policy_path
        with tempfile.TemporaryDirectory() as folder:
            if args.adapt_views:
                var_path, policy_path = adapted_to(room, base, args, Path(folder))
            evaluate_in_rooms(
                var_path, policy_path, [room], args.splits.split(","),
                episodes_per_intent=args.episodes_per_intent, seed=args.seed, on_cell=on_cell,
                goal_clips=None if args.household_voices is None else household_goals(args.household_voices),
            )  # fmt: skip
    return entry


def household_goals(seed: int) -> Callable[[str, str, str], "ClipBank"]:
    """A tier's goal clips as the household bench's synthesised family of `seed` records them."""
    from household import CLIPS_PER_COMMAND, MEMBERS, household_rows

    from learning.rl.rewards import ClipBank, clip_bank_of
    from learning.sounds import load_corpus

    def goals(sounds: str, split: str, front_end: str) -> ClipBank:
        corpus = load_corpus(sounds, front_end=front_end).subset(split)
        return clip_bank_of(corpus, household_rows(corpus, MEMBERS, CLIPS_PER_COMMAND, seed))

    return goals


def goal_clips_said(household_seed: int | None) -> str:
    if household_seed is None:
        return "every clip of the tier"
    from household import CLIPS_PER_COMMAND, MEMBERS

    return (
        f"the household bench's family of seed {household_seed}: {MEMBERS} speakers of the tier, "
        f"{CLIPS_PER_COMMAND} clips a command each"
    )


def adapted_to(room: str, base: BaseModel, args: argparse.Namespace, folder: Path) -> tuple[Path, Path]:
    """The base's VAR and policy adapted to `args.adapt_views` random views of `room` drawn with
    `args.adapt_seed`, as a household's robot is by POST …/models:adapt-to-room (worker.room_adaptation)."""
    import numpy as np

    from core.rooms import world_room
    from sim.explore import random_views
    from worker.room_adaptation import adapted_files

    views = random_views(
        args.world,
        args.adapt_views,
        seed=args.adapt_seed,
        image_size=base.image_size,
        domain=world_room(room),
    )
    images = np.stack([image for image, _, _ in views])
    var_path, policy_path, _ = adapted_files(
        base.var_path, base.policy_path, images, args.adapt_share, folder
    )
    assert policy_path is not None  # a base model always has a policy
    return var_path, policy_path


def room_names(text: str) -> list[str]:
    """Comma-separated room names; a name may change knobs (core.rooms.world_room),
    `lamplit_room[camera_jitter_m=0,camera_jitter_deg=0]`, whose commas do not separate rooms."""
    return [name for name in re.split(r",(?![^\[]*\])", text) if name]


def table(entry: dict, tag: str) -> Table:
    splits = sorted({split for cells in entry["cells"].values() for split in cells})
    view = Table(title=f"{tag}: zero-shot success of {entry['base']} ({entry['front_end']} front end)")
    view.add_column("room")
    for split in splits:
        view.add_column(split, justify="right")
    for room, cells in entry["cells"].items():
        view.add_row(escape(room), *(_cell(cells.get(split)) for split in splits))
    return view


def endings_table(entry: dict, tag: str) -> Table:
    """Where the episodes of each cell ended: for goal g, how many at each block (0..3) or at none. Right
    goals sit on the diagonal; a spread row means the goal was not understood, a large `none` that the robot
    did not arrive."""
    view = Table(title=f"{tag}: where the episodes ended (rows: goal; columns: block 0..3, none)")
    view.add_column("room / tier")
    view.add_column("goal", justify="right")
    view.add_column("ended at", justify="left")
    for room, cells in entry["cells"].items():
        for split, cell in cells.items():
            for goal, ended in enumerate(cell.get("final_view_by_intent", [])):
                label = f"{room} / {split}" if goal == 0 else ""
                view.add_row(escape(label), str(goal), " ".join(f"{count:3d}" for count in ended))
    return view


def _cell(cell: dict | None) -> str:
    return "—" if cell is None else f"{cell['success_rate']:.1%} ({cell['episodes']})"


def env_speed(rounds: int) -> dict[str, dict[str, float]]:
    """ms per step and per reset in each world, training room versus randomised rooms (96 px, one process)."""
    import gymnasium as gym
    import numpy as np

    import sim

    speeds: dict[str, dict[str, float]] = {}
    for world, env_id in sim.WORLDS.items():
        envs = {
            "training": gym.make(env_id, image_size=96),
            "randomised": gym.make(env_id, domain=RoomRanges()),
        }
        spent = {kind: {"reset_s": 0.0, "step_s": 0.0, "resets": 0, "steps": 0} for kind in envs}
        rng = np.random.default_rng(0)
        for episode in range(rounds):
            for kind, env in envs.items():
                tick = time.perf_counter()
                env.reset(seed=episode)
                spent[kind]["reset_s"] += time.perf_counter() - tick
                tick, truncated = time.perf_counter(), False
                while not truncated:
                    truncated = env.step(rng.uniform(-1, 1, 2).astype(np.float32))[3]
                    spent[kind]["steps"] += 1
                spent[kind]["step_s"] += time.perf_counter() - tick
                spent[kind]["resets"] += 1
        for env in envs.values():
            env.close()
        speeds[world] = {
            f"{kind}_{what}_ms": round(1000 * spent[kind][f"{what}_s"] / spent[kind][f"{what}s"], 2)
            for kind in envs
            for what in ("reset", "step")
        }
        print(world, speeds[world], flush=True)
    return speeds


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.env_speed:
        conditions = Conditions()
        measured = {"worlds": env_speed(args.rounds), "rounds": args.rounds, "image_size": 96}
        measured.update(conditions.finish())
        write_result(SPEED_RESULTS, {"benchmark": "rooms --env-speed", **measured})
        Console().print(describe(measured))
        return
    if not args.tag:
        raise SystemExit("--tag names the entry (e.g. before / after)")
    conditions = Conditions()
    command = " ".join(["bench/rooms.py", *(argv if argv is not None else sys.argv[1:])])

    def save(entry: dict) -> None:
        entry.update(conditions.finish())
        entry["measured"] = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
        entry["command"] = command
        entry["cells_done"] = sum(len(cells) for cells in entry["cells"].values())
        results = (
            json.loads(args.out.read_text()) if args.out.is_file() else {"benchmark": "rooms", "entries": {}}
        )
        results["entries"][args.tag] = entry
        write_result(args.out, results)

    entry = evaluate_base(args, save)
    console = Console()
    console.print(table(entry, args.tag))
    console.print(endings_table(entry, args.tag))
    console.print(describe(entry))


if __name__ == "__main__":
    main()
