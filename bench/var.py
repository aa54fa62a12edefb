"""VAR benchmark: collect simulated triplets, train, evaluate per unheard tier; writes bench/results/var.json.

    nice -n 10 .venv/bin/python bench/var.py --rows kuka-wordset            # the paper's 50,000 triplets
    .venv/bin/python bench/var.py --rows kuka-wordset,turtlebot-objects,kuka-notes --triplets 10000  # reduced

Resumable: datasets are reused when complete and training continues from its last checkpoint. Rows already in
var.json for other settings are kept; a row is replaced when it is run again.
"""

import argparse
import json
import resource
import sys
import time
from pathlib import Path

from conditions import Conditions, describe
from result_files import resolve, write_result
from rich.console import Console
from rich.table import Table

ROWS = {  # row → (world, sound set)
    "kuka-wordset": ("kuka", "wordset"),
    "turtlebot-objects": ("turtlebot", "objects"),
    "kuka-notes": ("kuka", "notes"),
}
PAPER_TRIPLETS = 50_000
RESULTS = Path(__file__).resolve().parent / "results"


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rows", default="kuka-wordset", help=f"comma-separated, from {', '.join(ROWS)}")
    parser.add_argument("--triplets", type=int, default=PAPER_TRIPLETS, help="training views per row")
    parser.add_argument("--test-views", type=int, default=4000, help="held-out views (another seed)")
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--image-size", type=int, default=96)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads; on a 2-core machine with other work running 1 is far faster",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--front-end", default="mfcc", help="sound front end: mfcc, speech-embedding or speech-embedding-fast"
    )
    parser.add_argument(
        "--room-copies", type=int, default=0, help="simulated-room copies of every training clip"
    )
    parser.add_argument(
        "--finetune",
        action="store_true",
        help="also fine-tune each row's VAR on a shifted room + a new voice, with and without replay",
    )
    parser.add_argument("--finetune-views", type=int, default=2000)
    return parser.parse_args()


def run_row(row: str, args: argparse.Namespace) -> dict:
    from core.paths import data_subdir
    from learning.sounds import load_corpus
    from learning.var.checkpoint import load_var
    from learning.var.dataset import collect_dataset
    from learning.var.evaluate import evaluate_var
    from learning.var.model import VARConfig
    from learning.var.plot import plot_sphere
    from learning.var.train import TrainConfig, train

    world, sounds = ROWS[row]
    corpus = load_corpus(sounds, front_end=args.front_end)
    size = args.image_size
    conditions = Conditions()
    training_views = collect_dataset(
        world,
        args.triplets,
        f"bench-{world}-{args.triplets}-{size}px-seed{args.seed}",
        seed=args.seed,
        image_size=size,
        workers=args.workers,
    )
    test_views = collect_dataset(
        world,
        args.test_views,
        f"bench-{world}-{args.test_views}-{size}px-test",
        seed=args.seed + 1000,
        image_size=size,
        workers=args.workers,
    )
    run_dir = data_subdir(
        "var", "bench", f"{result_key(row, args)}-{args.triplets}-{size}px-{args.epochs}ep-seed{args.seed}"
    )
    config = TrainConfig(
        dataset=str(training_views.path),
        sounds=sounds,
        run_dir=str(run_dir),
        model=VARConfig(front_end=args.front_end),
        epochs=args.epochs,
        sound_room_copies=args.room_copies,
        seed=args.seed,
        threads=args.threads,
    )
    result = train(config)
    var = load_var(result.checkpoint, manifest_hash=corpus.manifest_hash, front_end=args.front_end)
    scores = evaluate_var(var, test_views, corpus, seed=args.seed)
    sphere = plot_sphere(
        var,
        test_views,
        corpus,
        RESULTS / f"var_sphere_{result_key(row, args).replace('-', '_').replace(':', '_')}.png",
        splits=[s for s in scores["tiers"] if s != "train"],
    )
    return {
        "world": world,
        "sounds": sounds,
        "front_end": args.front_end,
        "room_copies": args.room_copies,
        "triplets": args.triplets,
        "reduced": args.triplets < PAPER_TRIPLETS,
        "image_size": size,
        "epochs": args.epochs,
        "test_views": args.test_views,
        "collection_seconds": training_views.meta["collection_seconds"],
        "collection_views_per_second": training_views.meta["views_per_second"],
        "training_seconds": round(result.seconds, 1),
        "training_triplets_per_second": round(result.triplets_per_second, 1),
        "peak_memory_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2),
        "held_out_val_accuracy": result.final_val_accuracy,
        "image_to_command": scores["image_to_command"],
        "tiers": scores["tiers"],
        "checkpoint": str(result.checkpoint),
        "training_dataset": str(training_views.path),
        "sphere_png": str(sphere.relative_to(RESULTS.parent.parent)),
        "train_config": json.loads(json.dumps(config.to_dict())),
        "measured": time.strftime("%Y-%m-%d %H:%M"),
        **conditions.finish(),
    }


NEW_VOICE = "flite:awb"  # a real (non-espeak) voice of the unheard-real-voices tier, the household's voice
NEW_VOICE_SPLIT = "unheard-real-voices"


def run_finetune(row: str, result: dict, args: argparse.Namespace) -> dict:
    """Fine-tune the row's VAR on views of a shifted room paired with one new voice; compare replay or not."""
    from core.paths import data_subdir
    from learning.sounds import load_corpus
    from learning.var.checkpoint import load_var
    from learning.var.dataset import SoundBank, collect_dataset
    from learning.var.evaluate import embed_images, triplet_accuracy
    from learning.var.finetune import finetune_config
    from learning.var.train import train
    from sim.domain import DomainShift

    world, sounds = ROWS[row]
    corpus = load_corpus(sounds, front_end=args.front_end)
    size, shifted = args.image_size, DomainShift.unseen_room()
    conditions = Conditions()
    new_room = collect_dataset(
        world,
        args.finetune_views,
        f"bench-{world}-{args.finetune_views}-{size}px-new-room",
        seed=args.seed + 2000,
        image_size=size,
        domain=shifted,
        workers=args.workers,
    )
    new_room_test = collect_dataset(
        world,
        args.test_views // 2,
        f"bench-{world}-{args.test_views // 2}-{size}px-new-room-test",
        seed=args.seed + 3000,
        image_size=size,
        domain=shifted,
        workers=args.workers,
    )
    old_room_test = collect_dataset(
        world,
        args.test_views,
        f"bench-{world}-{args.test_views}-{size}px-test",
        seed=args.seed + 1000,
        image_size=size,
        workers=args.workers,
    )
    voices = corpus.subset(NEW_VOICE_SPLIT)
    own = voices.speaker == NEW_VOICE
    banks = {
        "new room, new voice": (new_room_test, SoundBank.build(voices.features[own], voices.intent[own], 4)),
        "new room, other real voices": (
            new_room_test,
            SoundBank.build(voices.features[~own], voices.intent[~own], 4),
        ),
        "old room, unheard-easy": (old_room_test, SoundBank.from_corpus(corpus, "unheard-easy")),
    }

    def scores(checkpoint: str) -> dict:
        var = load_var(checkpoint)
        out = {}
        for name, (views, bank) in banks.items():
            accuracy = triplet_accuracy(
                embed_images(var, views.images), views.heard, var, bank, seed=args.seed
            )
            out[name] = {k: accuracy[k] for k in ("triplet_accuracy", "triplet_accuracy_in_view")}
        return out

    before = scores(str(resolve(result["checkpoint"])))
    outcome = {"views": args.finetune_views, "new_voice": NEW_VOICE, "before": before}
    for label, replay in (
        ("without replay", None),
        ("with replay", str(resolve(result["training_dataset"]))),
    ):
        run_dir = data_subdir(
            "var",
            "bench",
            f"{result_key(row, args)}-finetune-{args.finetune_views}-{'replay' if replay else 'plain'}",
        )
        config = finetune_config(
            result["checkpoint"],
            str(new_room.path),
            sounds,
            run_dir,
            sound_splits=(NEW_VOICE_SPLIT,),
            sound_speakers=(NEW_VOICE,),
            replay_dataset=replay,
            threads=args.threads,
        )
        trained = train(config)
        outcome[label] = {
            "steps": trained.steps,
            "seconds": round(trained.seconds, 1),
            "stopped_early": trained.stopped_early,
            **scores(str(trained.checkpoint)),
        }
    return {**outcome, **conditions.finish()}


def _pair(scores: dict) -> str:
    return f"{scores['triplet_accuracy']:.4f} / {scores['triplet_accuracy_in_view']:.4f}"


def print_finetune_table(row: str, outcome: dict) -> None:
    table = Table(
        title=f"{row}: fine-tuning on {outcome['views']} views of a shifted room + the voice "
        f"{outcome['new_voice']} (triplet accuracy / with a target in view)"
    )
    table.add_column("VAR")
    names = list(outcome["before"])
    for name in names:
        table.add_column(name)
    for label in ("before", "without replay", "with replay"):
        table.add_row(
            label,
            *(_pair(outcome[label][n]) for n in names),
        )
    Console(width=170).print(table)
    print(describe(outcome))


def print_table(results: dict) -> None:
    accuracies = "triplet accuracy (all, target in view, nothing in view)"
    table = Table(
        title=f"VAR on held-out views (another seed): {accuracies} and clip → image retrieval per tier"
    )
    for column in (
        "row",
        "triplets",
        "collect s (views/s)",
        "train s (triplets/s)",
        "peak GB",
        "image → command",
        "tier",
        "triplet acc",
        "in view",
        "nothing in view",
        "clip → image",
    ):
        table.add_column(column)
    for row, result in results.items():
        first = True
        for tier, scores in result["tiers"].items():
            head = (
                [
                    row,
                    f"{result['triplets']}{' (reduced)' if result['reduced'] else ''}",
                    f"{result['collection_seconds']:.0f} ({result['collection_views_per_second']:.0f})",
                    f"{result['training_seconds']:.0f} ({result['training_triplets_per_second']:.0f})",
                    f"{result['peak_memory_gb']:.2f}",
                    f"{result['image_to_command']:.4f}",
                ]
                if first
                else [""] * 6
            )
            table.add_row(
                *head,
                tier,
                f"{scores['triplet_accuracy']:.4f}",
                f"{scores['triplet_accuracy_in_view']:.4f}",
                f"{scores['triplet_accuracy_nothing_in_view']:.4f}",
                f"{scores['clip_to_image']:.4f}",
            )
            first = False
    Console(width=170).print(table)
    for row, result in results.items():
        print(f"{row}: {describe(result)}")


def result_key(row: str, args: argparse.Namespace) -> str:
    """A row's key in the results (and its run folders): the row, and its front end and room copies beside
    MFCC without copies, the paper's."""
    front_end = "" if args.front_end == "mfcc" else f":{args.front_end}"
    rooms = f":rooms{args.room_copies}" if args.room_copies else ""
    return f"{row}{front_end}{rooms}"


def _finished(result: dict | None, args: argparse.Namespace) -> bool:
    settings = {"triplets": args.triplets, "epochs": args.epochs, "image_size": args.image_size}
    return result is not None and all(result.get(k) == v for k, v in settings.items())


def main() -> None:
    args = parse_arguments()
    rows = args.rows.split(",")
    unknown = [row for row in rows if row not in ROWS]
    if unknown:
        sys.exit(f"unknown row(s) {unknown}; choose from {', '.join(ROWS)}")
    path = RESULTS / "var.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    keys = {row: result_key(row, args) for row in rows}
    for row, key in keys.items():
        if not (
            args.finetune and _finished(results.get(key), args)
        ):  # a finished row is reused for fine-tuning
            results[key] = run_row(row, args)
            write_result(path, results)
        if args.finetune:
            results[key]["finetune"] = run_finetune(row, results[key], args)
            write_result(path, results)
    print_table({key: results[key] for key in keys.values()})
    for key in keys.values():
        if "finetune" in results[key]:
            print_finetune_table(key, results[key]["finetune"])
    print(f"written: {path}")


if __name__ == "__main__":
    main()
