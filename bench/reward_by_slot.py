"""Where a VAR's intrinsic reward points: the scripted oracle holds the gripper over each Kuka slot, and the
reward f_I(image) · f_S(command) is read for every command (f_S = mean embedding of a tier's clips).

A diagonal that dominates its row means the reward leads to the right block; a weak diagonal entry is a
command the policy has little to climb towards. `--room` reads it in a held-out room (core.rooms): how much of
the guidance a room's look leaves. The margins summarise each command: its reward over its own slot less the
best of the other slots, and less the reward with nothing reached (the reset view). Seconds on a CPU.

    .venv/bin/python bench/reward_by_slot.py [--var worker/base_models/kuka/var.pt] [--split unheard-easy]
        [--room training|unseen_room|lamplit_room] [--out FILE]
"""

import argparse
from pathlib import Path

import gymnasium
import numpy as np
import torch
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table

from core.rooms import HELD_OUT_ROOMS, TRAINING_ROOM, world_room

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "reward_by_slot.json"


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--var", type=Path, default=ROOT / "worker" / "base_models" / "kuka" / "var.pt")
    parser.add_argument("--sounds", default="wordset")
    parser.add_argument("--split", default="unheard-easy")
    parser.add_argument("--episodes", type=int, default=5, help="episodes per slot")
    parser.add_argument("--steps", type=int, default=60, help="oracle steps before the image is read")
    parser.add_argument("--room", default=TRAINING_ROOM, choices=[TRAINING_ROOM, *HELD_OUT_ROOMS])
    parser.add_argument("--out", type=Path, default=RESULT)
    return parser.parse_args()


def command_centroids(var: torch.nn.Module, sounds: str, split: str) -> np.ndarray:
    from learning.rl.rewards import corpus_bank

    bank = corpus_bank(sounds, split, front_end=var.config.front_end).embed(var)
    embedded = bank.embeddings.numpy()
    return np.stack([embedded[bank.intents == k].mean(axis=0) for k in range(int(bank.intents.max()) + 1)])


def main() -> None:
    import sim
    from learning.var.checkpoint import load_var
    from sim.oracle import oracle_action

    args = parse_args()
    conditions = Conditions()
    torch.set_num_threads(1)
    var = load_var(args.var).eval()
    centroids = command_centroids(var, args.sounds, args.split)
    room = world_room(args.room)
    env = gymnasium.make(sim.world_id("kuka"), image_size=int(var.config.image_size), domain=room)
    over_slot = np.zeros((len(centroids), len(centroids)))
    at_reset = np.zeros(len(centroids))
    for slot in range(len(centroids)):
        for episode in range(args.episodes):
            observation, _ = env.reset(seed=100 + episode, options={"intent": slot})
            if slot == 0:
                at_reset += embed_and_score(var, observation["image"], centroids) / args.episodes
            for _ in range(args.steps):
                observation, *_ = env.step(oracle_action(env.unwrapped))
            over_slot[slot] += embed_and_score(var, observation["image"], centroids) / args.episodes
    env.close()
    report(args, over_slot, at_reset, conditions.finish())


def embed_and_score(var: torch.nn.Module, image: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    with torch.inference_mode():
        embedding = var.encode_image(torch.from_numpy(image[None])).numpy()[0]
    return centroids @ embedding


def report(args: argparse.Namespace, over_slot: np.ndarray, at_reset: np.ndarray, measured: dict) -> None:
    title = f"f_I · f_S with the gripper over each slot ({args.split} commands, {args.room} room)"
    table = Table(title=title)
    table.add_column("gripper over")
    for k in range(len(at_reset)):
        table.add_column(f"command {k}", justify="right")
    for slot, row in enumerate(over_slot):
        table.add_row(f"slot {slot}", *(f"{v:+.2f}" for v in row))
    table.add_row("nothing (reset)", *(f"{v:+.2f}" for v in at_reset))
    over_others, over_nothing = margins(over_slot, at_reset)
    table.add_row("margin over the other slots", *(f"{v:+.2f}" for v in over_others))
    table.add_row("margin over nothing", *(f"{v:+.2f}" for v in over_nothing))
    Console().print(table)
    print(describe(measured))
    write_result(
        args.out,
        {
            "var": str(args.var),
            "sounds": args.sounds,
            "split": args.split,
            "room": args.room,
            "episodes_per_slot": args.episodes,
            "oracle_steps": args.steps,
            "reward_over_slot": over_slot.round(4).tolist(),
            "reward_at_reset": at_reset.round(4).tolist(),
            "margin_over_other_slots": over_others.round(4).tolist(),
            "margin_over_nothing": over_nothing.round(4).tolist(),
            **measured,
        },
    )
    print(f"wrote {args.out}")


def margins(over_slot: np.ndarray, at_reset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per command k: reward at slot k less the best other slot, and less the reward at the reset view."""
    own = np.diag(over_slot)
    others = np.where(np.eye(len(own), dtype=bool), -np.inf, over_slot.T).max(axis=1)
    return own - others, own - at_reset


if __name__ == "__main__":
    main()
