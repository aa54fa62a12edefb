"""The sound front ends compared on the Kuka/Wordset unheard tiers: MFCC (the paper's) and speech-embedding.

    nice -n 10 .venv/bin/python bench/front_ends.py            # ~15 minutes on the shared 2-core machine
    nice -n 10 .venv/bin/python bench/front_ends.py --steps 6000 --views 8000

Per front end: a small VAR trained on the same Kuka views and Wordset training clips (both at once, one
thread each), then on the unheard tiers
- nearest-command accuracy: how often a clip's f_S embedding is nearest the mean direction of its own
  command among the training clips (what a goal clip must do for the policy to head for the right block);
- triplet accuracy on held-out views (seed 1000, the same for every --seed), as `varbot var eval` reports
  it, and image → command:
  how often a held-out view with a block under the gripper embeds nearest that block's command (f_I's side
  of the reward);
- ms per clip: CPU milliseconds (and wall) from WAV bytes to features, over the corpus's clips and over 1 s.
A row with no training, `speech-embedding frozen`, reads the frozen embedding mean- and max-pooled over the
clip, standardised, against the class centroids of the training clips: what the embedding knows before f_S
learns anything. Results: bench/results/front_ends.json with /proc/loadavg before and after (of the last
run: a finished training is reused, and its own seconds come from its metrics).
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUT = RESULTS / "front_ends.json"
SOUNDS = "wordset"
WORLD = "kuka"
FRONT_ENDS = ("mfcc", "speech-embedding")
TIERS = ("unheard-easy", "unheard-real-voices")
TIMED_CLIPS = 100


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=1000, help="VAR training steps per front end")
    parser.add_argument("--views", type=int, default=3000, help="Kuka training views")
    parser.add_argument("--test-views", type=int, default=1000, help="held-out views (seed 1000)")
    parser.add_argument("--image-size", type=int, default=48)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def prepare(args: argparse.Namespace):
    """The corpus (built if missing), every front end's features (cached), training and test views."""
    from learning.sounds import load_corpus
    from learning.sounds.build import build_corpora

    build_corpora([SOUNDS], progress=False, log=lambda _: None)
    corpora = {name: load_corpus(SOUNDS, front_end=name, progress=True) for name in FRONT_ENDS}
    return corpora, *kuka_views(args)


TEST_VIEWS_SEED = 1000


def kuka_views(args: argparse.Namespace):
    """The Kuka views the VARs train on (--views, from --seed) and are scored on (--test-views: seed 1000
    whatever --seed is, so that every seed of a recipe is scored on the same held-out views)."""
    from learning.var.dataset import collect_dataset

    size = args.image_size
    train_views = collect_dataset(
        WORLD, args.views, f"bench-front-ends-{args.views}-{size}px-seed{args.seed}", seed=args.seed,
        image_size=size, workers=2,
    )  # fmt: skip
    test_views = collect_dataset(
        WORLD, args.test_views, f"bench-front-ends-{args.test_views}-{size}px-test", seed=TEST_VIEWS_SEED,
        image_size=size, workers=2,
    )  # fmt: skip
    return train_views, test_views


def run_dir(front_end: str, args: argparse.Namespace) -> Path:
    from core.paths import data_subdir

    name = f"{front_end}-{args.views}views-{args.image_size}px-{args.steps}steps-seed{args.seed}"
    return data_subdir("bench", "front_ends", name)


def train_all(train_views, args: argparse.Namespace) -> None:
    """Train one VAR per front end (those not already finished) at once, one thread each."""
    processes = {}
    for front_end in FRONT_ENDS:
        folder = run_dir(front_end, args)
        if (folder / "final.pt").exists():
            continue
        command = [
            str(Path(sys.executable).with_name("varbot")), "var", "train", str(train_views.path),
            "--sounds", SOUNDS, "--front-end", front_end, "--run-dir", str(folder),
            "--max-steps", str(args.steps), "--batch-size", str(args.batch_size), "--threads", "1",
            "--seed", str(args.seed),
        ]  # fmt: skip
        log = open(folder.with_suffix(".log"), "w")  # noqa: SIM115 (closed when the process ends)
        processes[front_end] = (subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT), log)
    for front_end, (process, log) in processes.items():
        if process.wait() != 0:
            raise SystemExit(f"training the {front_end} VAR failed; see {log.name}")
        log.close()


def training_seconds(front_end: str, args: argparse.Namespace) -> float:
    """The run's own training time (its last metrics record), whenever it was trained."""
    lines = (run_dir(front_end, args) / "metrics.jsonl").read_text().splitlines()
    return next(json.loads(line)["seconds"] for line in reversed(lines) if '"seconds"' in line)


def score_var(front_end: str, corpus, test_views, args: argparse.Namespace) -> dict:
    from learning.var.checkpoint import load_var
    from learning.var.evaluate import evaluate_var, nearest_command_accuracy

    var = load_var(
        run_dir(front_end, args) / "final.pt", manifest_hash=corpus.manifest_hash, front_end=front_end
    )
    train = corpus.subset("train")
    evaluation = evaluate_var(var, test_views, corpus, seed=args.seed)
    return {
        tier: {
            "nearest_command_accuracy": nearest_command_accuracy(var, train, corpus.subset(tier), 4)[0],
            "triplet_accuracy": evaluation["tiers"][tier]["triplet_accuracy"],
            "clips": evaluation["tiers"][tier]["clips"],
        }
        for tier in TIERS
    } | {"image_to_command": evaluation["image_to_command"]}


def score_frozen(corpus, tiers: tuple[str, ...] = TIERS) -> dict:
    """Nearest class centroid of the standardised mean- and max-pooled frozen features (the embedding, or
    MFCC): no training."""
    import numpy as np

    def pooled(features: np.ndarray) -> np.ndarray:
        heard = (features != 0).any(axis=2, keepdims=True)
        mean = features.sum(axis=1) / heard.sum(axis=1).clip(min=1)
        return np.concatenate([mean, np.where(heard, features, -np.inf).max(axis=1)], axis=1)

    train = corpus.subset("train")
    known = pooled(train.features)
    centre, scale = known.mean(axis=0), known.std(axis=0) + 1e-6
    centroids = np.stack([((known - centre) / scale)[train.intent == k].mean(axis=0) for k in range(4)])
    scores = {}
    for tier in tiers:
        clips = corpus.subset(tier)
        distances = ((((pooled(clips.features) - centre) / scale)[:, None] - centroids) ** 2).sum(axis=2)
        hits = distances.argmin(axis=1) == clips.intent
        scores[tier] = {"nearest_command_accuracy": float(hits.mean()), "clips": len(hits)}
    return scores


def ms_per_clip(front_end: str, corpus) -> dict:
    """CPU and wall milliseconds from WAV bytes to features, over corpus clips and over clips cut to 1 s."""
    import numpy as np

    from learning.audio import decode_audio, encode_wav, features_from_bytes

    clips = [Path(path).read_bytes() for path in corpus.clip[:: max(1, len(corpus.clip) // TIMED_CLIPS)]]
    one_second = [encode_wav(np.resize(decode_audio(clip)[0], 16_000)) for clip in clips]
    features_from_bytes(clips[0], "speech", front_end)  # load the models once
    timings = {}
    for name, batch in (("corpus_clip", clips), ("one_second_clip", one_second)):
        cpu, wall = time.process_time(), time.perf_counter()
        for clip in batch:
            features_from_bytes(clip, "speech", front_end)
        timings[f"cpu_ms_per_{name}"] = round((time.process_time() - cpu) / len(batch) * 1000, 2)
        timings[f"wall_ms_per_{name}"] = round((time.perf_counter() - wall) / len(batch) * 1000, 2)
    return timings


def main() -> None:
    import torch

    args = parse_arguments()
    conditions = Conditions()
    corpora, train_views, test_views = prepare(args)
    train_all(train_views, args)
    torch.set_num_threads(1)  # after the training processes started; ms per clip on one core
    rows = {}
    for front_end in FRONT_ENDS:
        rows[front_end] = {
            **score_var(front_end, corpora[front_end], test_views, args),
            **ms_per_clip(front_end, corpora[front_end]),
            "training_seconds": training_seconds(front_end, args),  # trained at once, sharing the machine
        }
    rows["speech-embedding frozen"] = score_frozen(corpora["speech-embedding"])
    result = {
        "benchmark": "front_ends",
        "world": WORLD,
        "sounds": SOUNDS,
        "settings": vars(args),
        "rows": rows,
        "measured": time.strftime("%Y-%m-%d %H:%M"),
        **conditions.finish(),
    }
    write_result(OUTPUT, result)
    print_table(result)


def print_table(result: dict) -> None:
    settings = result["settings"]
    table = Table(
        title=f"Sound front ends, Kuka/Wordset: VAR of {settings['steps']} steps on {settings['views']} "
        f"views ({settings['image_size']} px)"
    )
    columns = ["front end"]
    for tier in TIERS:
        short = tier.removeprefix("unheard-")
        columns += [f"{short}: nearest cmd", f"{short}: triplet"]
    columns += ["image → cmd", "CPU ms/clip", "CPU ms/1 s"]
    for column in columns:
        table.add_column(column, justify="left" if column == "front end" else "right")
    for name, row in result["rows"].items():
        cells = [name]
        for tier in TIERS:
            cells.append(f"{row[tier]['nearest_command_accuracy']:.1%}")
            triplet = row[tier].get("triplet_accuracy")
            cells.append("—" if triplet is None else f"{triplet:.1%}")
        cells.append(f"{row['image_to_command']:.1%}" if "image_to_command" in row else "—")
        for key in ("cpu_ms_per_corpus_clip", "cpu_ms_per_one_second_clip"):
            cells.append(f"{row[key]:.1f}" if key in row else "—")
        table.add_row(*cells)
    Console().print(table)
    print(describe(result))
    print(f"written: {OUTPUT}")


if __name__ == "__main__":
    main()
