"""Views worth labelling: how often the base model's own attempts at a household's commands end at a target,
and what a household's answers then give — the share of pair labels that are *is* and of triplets with a
spoken positive — for attempts mixed with random views (the product's default share) against random views
alone (the old capture). The simulator's ground truth only scores the views here; it never chooses them.

Each view is labelled for every recording of every command, as the Label page's answers are: an attempt at
the asked target gives *is* for that command's recordings and *is not* for the others'; a view showing
nothing gives *is not* for all (silence triplets).

    nice -n 10 .venv/bin/python bench/attempt_views.py --attempts 40
"""

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

from learning.sounds import load_corpus
from learning.var.checkpoint import front_end_of, load_var
from sim.explore import random_views
from worker.attempts import policy_player
from worker.base_models import find_base

RESULT = Path(__file__).resolve().parent / "results" / "attempt_views.json"
COMMANDS = 4


def view_labels(kind: str, recordings: int) -> tuple[int, int, int, int]:
    """(is, is not, spoken-positive triplets, silence triplets) that one view gives, labelled for every
    recording."""
    others = (COMMANDS - 1) * recordings
    if kind == "nothing":
        return 0, COMMANDS * recordings, 0, COMMANDS * recordings
    return recordings, others, recordings * others, 0


def shares(kinds: list[str], recordings: int) -> dict[str, float]:
    totals = np.sum([view_labels(kind, recordings) for kind in kinds], axis=0)
    is_, is_not, spoken, silence = (int(v) for v in totals)
    return {
        "is_share": is_ / max(1, is_ + is_not),
        "spoken_positive_triplet_share": spoken / max(1, spoken + silence),
    }


def attempt_outcomes(attempts: int, recordings: int, tier: str, seed: int) -> tuple[list[str], float]:
    base = find_base("kuka")
    var = load_var(base.var_path).eval()
    corpus = load_corpus("wordset", front_end=front_end_of(base.var_path)).subset(tier)
    rng = np.random.default_rng(seed)
    rows = {
        i: rng.choice(np.flatnonzero(corpus.intent == i), recordings, replace=False) for i in range(COMMANDS)
    }
    with torch.inference_mode():
        goals = {i: var.encode_sound(torch.from_numpy(corpus.features[r])) for i, r in rows.items()}
    outcomes = []
    start = time.perf_counter()
    with policy_player(base.policy_path, var, "kuka", None) as play:
        for index in tqdm(range(attempts), desc="attempts"):
            intent, take = index % COMMANDS, index // COMMANDS % recordings
            heard = play((goals[intent][take], corpus.features[rows[intent][take]]), seed + index).sim_heard
            outcomes.append("asked" if heard == intent else "nothing" if heard is None else "other")
    return outcomes, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--attempts", type=int, default=40)
    parser.add_argument("--recordings", type=int, default=2, help="recordings per command")
    parser.add_argument("--random-share", type=float, default=0.25, help="random views beside the attempts")
    parser.add_argument("--tier", default="unheard-easy")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    conditions = Conditions()
    outcomes, seconds = attempt_outcomes(args.attempts, args.recordings, args.tier, args.seed)
    randoms = max(1, round(args.attempts * args.random_share / (1 - args.random_share)))
    random_kinds = [
        "nothing" if heard is None else "target"
        for _, heard, _ in random_views("kuka", randoms, seed=args.seed, image_size=96)
    ]
    result = {
        "what": "base Kuka model's attempts at a household's commands: where they end, and what answers give",
        "command": "bench/attempt_views.py "
        + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
        "attempts": {kind: outcomes.count(kind) for kind in ("asked", "other", "nothing")},
        "attempt_seconds": round(seconds, 1),
        "random_views": {"count": randoms, "target_in_view": random_kinds.count("target")},
        "attempts_with_random_views": shares([*outcomes, *random_kinds], args.recordings),
        "random_views_alone": shares(random_kinds, args.recordings),
        **conditions.finish(),
    }
    write_result(RESULT, result)
    table = Table(title="Views worth labelling (Kuka base model)")
    for column in ("views", "is share", "triplets with a spoken positive"):
        table.add_column(column)
    for name in ("attempts_with_random_views", "random_views_alone"):
        table.add_row(
            name.replace("_", " "),
            f"{result[name]['is_share']:.1%}",
            f"{result[name]['spoken_positive_triplet_share']:.1%}",
        )
    console = Console()
    console.print(table)
    console.print(f"attempts ending at the asked target / another / none: {result['attempts']}")
    console.print(describe(result))


if __name__ == "__main__":
    main()
