"""How well each shipped base model's VAR reads voices it never heard (issues 22 and 23).

For every world with a base model (`worker.base_models.find_base`), on every unheard tier of the corpus its
VAR learnt from: nearest-command accuracy (how often a clip's f_S embedding is nearest the mean direction of
its own command among the corpus's training clips: a goal clip embedded nearer another command sends the
robot to the wrong object however well PPO trained), the mean margin (cosine to its own command minus the best
other) and which command each missed clip was read as. Nothing is trained. Prints a table and writes
bench/results/base_voices.json with the machine and the load average before and after.

    nice -n 10 .venv/bin/python bench/base_voices.py [--worlds kuka,turtlebot,kinova]
"""

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conditions import Conditions, describe
from result_files import relative_path, write_result
from rich.console import Console
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results" / "base_voices.json"
WORLDS = ("kuka", "turtlebot", "kinova")


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--worlds", default=",".join(WORLDS), help="comma-separated worlds")
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def score_tier(var, train, clips, names: list[str]) -> dict:  # type: ignore[no-untyped-def]
    from learning.var.evaluate import command_margins, command_similarities

    similarity = command_similarities(var, train, clips, len(names))
    read_as = similarity.argmax(axis=1)
    misread = Counter(
        f"{names[said]} read as {names[heard]}"
        for said, heard in zip(clips.intent.tolist(), read_as.tolist(), strict=True)
        if said != heard
    )
    return {
        "clips": len(clips.intent),
        "nearest_command_accuracy": round(float((read_as == clips.intent).mean()), 4),
        "by_command": {
            names[k]: round(float((read_as[clips.intent == k] == k).mean()), 4)
            for k in range(len(names))
            if (clips.intent == k).any()
        },
        "mean_margin": round(float(command_margins(similarity, clips.intent).mean()), 4),
        "misread": dict(misread.most_common()),
    }


def score_base(world: str) -> dict | None:
    from learning.sounds import load_corpus
    from learning.var.checkpoint import load_var
    from learning.var.evaluate import unheard_tiers
    from worker.base_models import BaseModelMissing, find_base

    try:
        base = find_base(world)
    except BaseModelMissing:
        return None
    var = load_var(base.var_path)
    sounds = base.record.get("sounds", "wordset")
    corpus = load_corpus(sounds, front_end=var.front_end, progress=True)
    train = corpus.subset("train")
    return {
        "base_model": relative_path(base.folder),
        "built_at": base.record.get("built_at"),
        "sounds": sounds,
        "front_end": var.front_end,
        "tiers": {
            tier: score_tier(var, train, corpus.subset(tier), list(corpus.intent_names))
            for tier in unheard_tiers(corpus)
        },
    }


def main(argv: list[str] | None = None) -> dict:
    import torch

    args = parse_arguments(argv)
    torch.set_num_threads(1)
    conditions = Conditions()
    worlds = {}
    for world in args.worlds.split(","):
        scored = score_base(world)
        worlds[world] = scored if scored is not None else {"base_model": None}
    result = {
        "benchmark": "base_voices",
        "worlds": worlds,
        "measured": time.strftime("%Y-%m-%d %H:%M"),
        **conditions.finish(),
        "command": " ".join(["python", "bench/base_voices.py", *(sys.argv[1:] if argv is None else argv)]),
    }
    write_result(args.out, result)
    print_table(result, args.out)
    return result


def print_table(result: dict, out: Path) -> None:
    table = Table(title="Shipped base models: nearest-command accuracy on unheard voices")
    for column in ("world", "front end", "tier", "clips", "nearest command", "mean margin", "most misread"):
        table.add_column(column)
    for world, scored in result["worlds"].items():
        if scored["base_model"] is None:
            table.add_row(world, "no base model", "", "", "", "", "")
            continue
        for tier, row in scored["tiers"].items():
            worst = next(iter(row["misread"].items()), None)
            table.add_row(
                world, scored["front_end"], tier, str(row["clips"]), f"{row['nearest_command_accuracy']:.1%}",
                f"{row['mean_margin']:.3f}", f"{worst[0]} ({worst[1]})" if worst else "—",
            )  # fmt: skip
    Console().print(table)
    print(describe(result))
    print(f"written: {out}")


if __name__ == "__main__":
    main()
