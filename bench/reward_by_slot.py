"""Where a VAR's intrinsic reward points: the scripted oracle holds the gripper over each Kuka slot, and the
reward f_I(image) · f_S(command) is read for every command (f_S = mean embedding of a tier's clips).

A diagonal that dominates its row means the reward leads to the right block; a weak diagonal entry is a
command the policy has little to climb towards. Seconds on a CPU.

    .venv/bin/python bench/reward_by_slot.py [--var worker/base_models/kuka/var.pt] [--split unheard-easy]
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
    return parser.parse_args()


def command_centroids(var: torch.nn.Module, sounds: str, split: str) -> np.ndarray:
    from learning.rl.rewards import corpus_bank

    bank = corpus_bank(sounds, split).embed(var)
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
    env = gymnasium.make(sim.world_id("kuka"), image_size=int(var.config.image_size))
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
    table = Table(title=f"f_I · f_S with the gripper over each slot ({args.split} commands)")
    table.add_column("gripper over")
    for k in range(len(at_reset)):
        table.add_column(f"command {k}", justify="right")
    for slot, row in enumerate(over_slot):
        table.add_row(f"slot {slot}", *(f"{v:+.2f}" for v in row))
    table.add_row("nothing (reset)", *(f"{v:+.2f}" for v in at_reset))
    Console().print(table)
    print(describe(measured))
    write_result(
        RESULT,
        {
            "var": str(args.var),
            "sounds": args.sounds,
            "split": args.split,
            "episodes_per_slot": args.episodes,
            "oracle_steps": args.steps,
            "reward_over_slot": over_slot.round(4).tolist(),
            "reward_at_reset": at_reset.round(4).tolist(),
            **measured,
        },
    )
    print(f"wrote {RESULT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
