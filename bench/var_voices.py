"""How well the VAR's sound encoder understands voices it never heard, chosen without the test voices.

    nice -n 5 .venv/bin/python bench/var_voices.py --fold variants    # both variants, in parallel
    nice -n 5 .venv/bin/python bench/var_voices.py --fold accent
    nice -n 5 .venv/bin/python bench/var_voices.py --fold accent-and-engines --variants speed4 --steps 4800

The policy heads for whichever command a goal clip embeds nearest, so a clip that lands nearer another
command's direction sends the robot to the wrong object however well PPO trained. This bench measures that
rate, `nearest-command accuracy`, and the mean margin (cosine to the clip's own command minus the best other),
on a validation fold made only of *training* voices, removed from the VAR's clips and scored afterwards:
- `variants`: the espeak-ng variants in `HELD_OUT_VARIANTS` (new voices, known accents);
- `accent`: every espeak-ng voice with the accent `HELD_OUT_ACCENT` (known variants, a new accent);
- `accent-and-engines`: those and every voice of the other synthesizers (flite, festival) as well, the
  hardest fold: the VAR keeps 23 espeak-ng voices, and the other engines' voices differ from them most.
The unheard test tiers are not read here; `bench/reproduce.py` reports them for the variant chosen here.

Variants: the training recipe of `bench/reproduce.py` (2,400 steps on the reproduce-kuka-50000 views), with
and without speed-perturbed copies of the training clips (`varbot var train --speed-copies`). Both train at
once, one thread each. Results: `bench/results/var_voices.json` (per variant and per held-out speaker); a
run with another --steps or --seed is kept beside the default one as `<variant>-<steps>steps-seed<seed>`.
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
OUTPUT = RESULTS / "var_voices.json"
DATASET = "reproduce-kuka-50000"
SOUNDS = "wordset"
STEPS = 2400
SEED = 0
# Eight espeak-ng variants that occur once in the training voices: a fold of voices whose variant is new.
HELD_OUT_VARIANTS = ("m4", "m1", "paul", "f4", "f3", "max", "f2", "m3")
HELD_OUT_ACCENT = "en-us"
FOLDS = ("variants", "accent", "accent-and-engines")
VARIANTS = {
    "baseline": [],
    "speed4": ["--speed-copies", "4", "--speed-range", "0.85,1.15"],
}


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated: {list(VARIANTS)}")
    parser.add_argument("--fold", choices=FOLDS, default="variants", help="which training voices to hold out")
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--seed", type=int, default=SEED)
    return parser.parse_args()


def validation_fold(corpus, fold: str) -> tuple[list[str], list[str]]:
    """(training speakers the VAR keeps, held-out training speakers) of the train split."""
    speakers = sorted(set(corpus.subset("train").speaker.tolist()))
    if fold == "variants":
        held_out = [s for s in speakers if _espeak_parts(s)[0] in HELD_OUT_VARIANTS]
    elif fold == "accent":
        held_out = [s for s in speakers if _espeak_parts(s)[1] == HELD_OUT_ACCENT]
    else:
        held_out = [s for s in speakers if _espeak_parts(s)[1] in (HELD_OUT_ACCENT, None)]
    return [s for s in speakers if s not in held_out], held_out


def _espeak_parts(speaker: str) -> tuple[str | None, str | None]:
    """espeak-ng:t08-m4-en-gb-x-rp-p56-s188 → (m4, en-gb-x-rp); recorded voices have neither."""
    engine, _, name = speaker.partition(":")
    if engine != "espeak-ng":
        return None, None
    parts = name.split("-")
    return parts[1], "-".join(parts[2:-2])


def run_dir(variant: str, args: argparse.Namespace) -> Path:
    from core.paths import data_subdir

    return data_subdir("bench", "var_voices", f"{args.fold}-{variant}-{args.steps}steps-seed{args.seed}")


def train_all(variants: list[str], kept: list[str], args: argparse.Namespace) -> dict[str, float]:
    """Train every variant not already finished, concurrently; returns wall seconds per variant."""
    started, processes = time.monotonic(), {}
    for name in variants:
        folder = run_dir(name, args)
        if (folder / "final.pt").exists():
            continue
        command = [
            str(Path(sys.executable).with_name("varbot")), "var", "train", DATASET, "--sounds", SOUNDS,
            "--run-dir", str(folder), "--max-steps", str(args.steps), "--threads", "1",
            "--seed", str(args.seed), "--speakers", ",".join(kept), *VARIANTS[name],
        ]  # fmt: skip
        log = open(folder.with_suffix(".log"), "w")  # noqa: SIM115 (closed when the process ends)
        processes[name] = (subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT), log)
    seconds = {}
    for name, (process, log) in processes.items():
        if process.wait() != 0:
            raise SystemExit(f"training {name} failed; see {log.name}")
        log.close()
        seconds[name] = time.monotonic() - started
    return seconds


def score(variant: str, corpus, kept: list[str], held_out: list[str], args: argparse.Namespace) -> dict:
    import numpy as np

    from learning.var.checkpoint import load_var
    from learning.var.evaluate import command_margins, command_similarities

    train = corpus.subset("train")
    known, unknown = train.by_speakers(kept), train.by_speakers(held_out)
    var = load_var(run_dir(variant, args) / "final.pt")
    similarity = command_similarities(var, known, unknown, len(corpus.intent_names))
    hits = similarity.argmax(axis=1) == unknown.intent
    margin = command_margins(similarity, unknown.intent)
    per_speaker = {s: float(hits[unknown.speaker == s].mean()) for s in held_out}
    return {
        "held_out_accuracy": float(hits.mean()),
        "mean_margin": float(margin.mean()),
        "smallest_margin": float(margin.min()),
        "held_out_clips": len(hits),
        "worst_speaker_accuracy": float(np.min(list(per_speaker.values()))),
        "per_speaker": per_speaker,
        "training_speakers": len(kept),
        "arguments": VARIANTS[variant],
    }


def main() -> None:
    from learning.sounds import load_corpus

    args = parse_arguments()
    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        raise SystemExit(f"unknown variant(s) {unknown}; choose from {list(VARIANTS)}")
    corpus = load_corpus(SOUNDS)
    kept, held_out = validation_fold(corpus, args.fold)
    conditions = Conditions()
    seconds = train_all(variants, kept, args)
    results = json.loads(OUTPUT.read_text()) if OUTPUT.exists() else {"benchmark": "var_voices", "folds": {}}
    results.update(dataset=DATASET, sounds=SOUNDS)
    fold = results["folds"].setdefault(args.fold, {"held_out": held_out, "variants": {}})
    scores = {name: score(name, corpus, kept, held_out, args) for name in variants}
    measured = conditions.finish()  # the variants trained side by side, under the same conditions
    for name in variants:
        record = {**scores[name], "steps": args.steps, "seed": args.seed, **measured}
        if name in seconds:
            record["wall_s_trained_in_parallel"] = seconds[name]
        key = (
            name if (args.steps, args.seed) == (STEPS, SEED) else f"{name}-{args.steps}steps-seed{args.seed}"
        )
        fold["variants"][key] = {**fold["variants"].get(key, {}), **record}
    write_result(OUTPUT, results)
    print_table(args.fold, fold)


def print_table(name: str, fold: dict) -> None:
    title = f"fold '{name}': nearest-command accuracy on {len(fold['held_out'])} held-out training voices"
    table = Table(title=title)
    for column in ("variant", "accuracy", "worst voice", "mean margin", "smallest margin", "clips"):
        table.add_column(
            column, justify="left" if column == "variant" else "right", no_wrap=column == "variant"
        )
    for variant, record in fold["variants"].items():
        table.add_row(
            variant,
            f"{record['held_out_accuracy']:.1%}",
            f"{record['worst_speaker_accuracy']:.1%}",
            f"{record['mean_margin']:.3f}",
            f"{record['smallest_margin']:.3f}",
            str(record["held_out_clips"]),
        )
    Console().print(table)
    for variant, record in fold["variants"].items():
        print(f"{variant}: {describe(record)}")
    print(f"written: {OUTPUT}")


if __name__ == "__main__":
    main()
