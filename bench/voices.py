"""Voices nobody tuned to (issue 22): both sound front ends on every set's unheard tiers, per language, and in
simulated rooms.

    nice -n 10 .venv/bin/python bench/voices.py          # ~20-40 min on the shared 2-core machine
    nice -n 10 .venv/bin/python bench/voices.py --runs wordset-multilingual:speech-embedding:2 --steps 2000

A run is SET:FRONT_END:ROOM_COPIES[:SPEED_COPIES[:VOICE_COPIES]]: a small VAR trained on the same Kuka views
(intent k = slot k for every set) with the set's training clips plus ROOM_COPIES recordings of each in
simulated training rooms (`varbot var train --room-copies`), SPEED_COPIES played faster or slower and
VOICE_COPIES with the formants moved (`--speed-copies`, `--voice-copies`). Each run is scored on each of
its set's unheard tiers:
- nearest-command accuracy: a clip's f_S embedding nearest the mean direction of its own command among the
  training clips (what a goal clip must do for the policy to head for the right block);
- triplet accuracy on held-out views (seed 1000, the same for every --seed), as `varbot var eval` reports
  it; image -> command.
The multilingual Wordset has one unheard tier per language (unheard-en, unheard-de, ...) and unheard-room
(further unheard speakers of every language, recorded in simulated rooms). A set without an unheard-room tier
gets one here, `unheard-room (derived)`: every unheard clip recorded in a room drawn from a stream no
training copy uses, the same rooms for both front ends.
Rows with no training, `frozen`, read each front end's features mean- and max-pooled and standardised against
the training clips' class centroids. CPU ms per clip: one thread, from WAV bytes to features (Wordset clips,
and clips cut to 1 s). Runs train two at a time (one thread each) and a finished run is reused (its seconds
come from its metrics). Results: bench/results/voices.json with /proc/loadavg before and after (of the last
run: trainings it reused ran earlier, at the load of their own time).
"""

import argparse
import dataclasses
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from conditions import Conditions, describe
from front_ends import kuka_views, ms_per_clip, score_frozen
from result_files import write_result
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUT = RESULTS / "voices.json"
WORLD = "kuka"
FRONT_ENDS = ("mfcc", "speech-embedding", "speech-embedding-fast")
DEFAULT_RUNS = (
    "wordset-multilingual:speech-embedding:2:2",
    "wordset-multilingual:speech-embedding-fast:2:2",
    "wordset-multilingual:speech-embedding:2",
    "wordset-multilingual:mfcc:2",
    "wordset:speech-embedding:2",
    "wordset:speech-embedding-fast:2",
    "wordset:mfcc:2",
    "notes:speech-embedding:0",
    "notes:mfcc:0",
    "mix:speech-embedding:0",
    "mix:mfcc:0",
)
ROOM_TIER = "unheard-room"
DERIVED_ROOM_TIER = "unheard-room (derived)"
DERIVED_ROOM_STREAM = 1_000_003  # apart from the corpora's room tiers and the training copies' stream
TIMED_SET = "wordset"


@dataclasses.dataclass(frozen=True)
class Run:
    sounds: str
    front_end: str
    room_copies: int
    speed_copies: int = 0
    voice_copies: int = 0

    @classmethod
    def parse(cls, text: str) -> "Run":
        from learning.front_ends import check_front_end
        from learning.sounds import sound_set

        try:
            sounds, front_end, *copies = text.split(":")
            if len(copies) not in (1, 2, 3):
                raise ValueError("one to three numbers of copies")
            counts = [int(count) for count in copies]
            run = cls(sound_set(sounds).name, check_front_end(front_end), *counts)
        except ValueError as error:
            raise SystemExit(
                f"--runs: {text!r} is not SET:FRONT_END:ROOM_COPIES[:SPEED_COPIES[:VOICE_COPIES]] ({error})"
            ) from None
        return run

    @property
    def key(self) -> str:
        speed = f":speed{self.speed_copies}" if self.speed_copies else ""
        voice = f":voice{self.voice_copies}" if self.voice_copies else ""
        return f"{self.sounds}:{self.front_end}:rooms{self.room_copies}{speed}{voice}"


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", default=",".join(DEFAULT_RUNS), help="comma-separated SET:FRONT_END:COPIES")
    parser.add_argument("--steps", type=int, default=700, help="VAR training steps per run")
    parser.add_argument("--views", type=int, default=3000, help="Kuka training views")
    parser.add_argument("--test-views", type=int, default=1000, help="held-out views (seed 1000)")
    parser.add_argument("--image-size", type=int, default=48)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--sound-hidden", type=int, help="width of f_S's layers (default: the VAR's, 128)")
    parser.add_argument("--parallel", type=int, default=2, help="runs trained at once, one thread each")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default=str(OUTPUT), help="where the JSON goes")
    return parser.parse_args()


def run_dir(run: Run, args: argparse.Namespace) -> Path:
    from core.paths import data_subdir

    copies = f"-speed{run.speed_copies}" if run.speed_copies else ""
    copies += f"-voice{run.voice_copies}" if run.voice_copies else ""
    copies += f"-width{args.sound_hidden}" if args.sound_hidden else ""
    # the corpus's manifest hash: a VAR trained before the corpus changed is never taken as this run's
    name = (
        f"{run.sounds}-{run.front_end}-rooms{run.room_copies}{copies}-{args.views}views-{args.image_size}px-"
        f"{args.steps}steps-seed{args.seed}-{args.corpus_hashes[run.sounds][:8]}"
    )
    return data_subdir("bench", "voices", name)


def train_runs(runs: list[Run], train_views, args: argparse.Namespace) -> None:
    """Train every run not finished yet, `--parallel` at a time (one thread each)."""
    pending = [run for run in runs if not (run_dir(run, args) / "final.pt").exists()]
    with tqdm(total=len(pending), desc="VARs", unit="run") as bar:
        for start in range(0, len(pending), args.parallel):
            batch = pending[start : start + args.parallel]
            processes = [(run, *start_training(run, train_views, args)) for run in batch]
            for run, process, log in processes:
                if process.wait() != 0:
                    raise SystemExit(f"training {run.key} failed; see {log.name}")
                log.close()
                bar.update()


def start_training(run: Run, train_views, args: argparse.Namespace):
    folder = run_dir(run, args)
    command = [
        str(Path(sys.executable).with_name("varbot")), "var", "train", str(train_views.path),
        "--sounds", run.sounds, "--front-end", run.front_end, "--room-copies", str(run.room_copies),
        "--speed-copies", str(run.speed_copies), "--voice-copies", str(run.voice_copies),
        "--run-dir", str(folder), "--max-steps", str(args.steps), "--batch-size", str(args.batch_size),
        "--threads", "1", "--seed", str(args.seed),
        *(["--sound-hidden", str(args.sound_hidden)] if args.sound_hidden else []),
    ]  # fmt: skip
    log = open(folder.with_suffix(".log"), "w")  # noqa: SIM115 (closed when the process ends)
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT), log


def training_seconds(run: Run, args: argparse.Namespace) -> float:
    import json

    lines = (run_dir(run, args) / "metrics.jsonl").read_text().splitlines()
    return next(json.loads(line)["seconds"] for line in reversed(lines) if '"seconds"' in line)


def room_recordings(corpus, seed: int) -> list[np.ndarray]:
    """Every unheard clip of the corpus recorded in a room of the derived tier's stream."""
    from learning.audio import decode_audio
    from learning.room_acoustics import record_in_room

    rng = np.random.default_rng([seed, DERIVED_ROOM_STREAM])
    clips = corpus.subset(unheard_of(corpus)).clip
    return [
        record_in_room(decode_audio(Path(path).read_bytes())[0], rng)
        for path in tqdm(clips, desc=f"{corpus.name}: rooms", unit="clip")
    ]


def with_room_tier(corpus, recordings: dict[str, list[np.ndarray]], seed: int):
    """The corpus, plus a derived unheard-room tier when it has none: every unheard clip recorded in a room
    (the same recordings whatever the front end; `recordings` keeps them per set)."""
    from learning.audio import features_from_waveform

    if ROOM_TIER in corpus.splits:
        return corpus
    unheard = corpus.subset(unheard_of(corpus))
    if corpus.name not in recordings:
        recordings[corpus.name] = room_recordings(corpus, seed)
    features = np.stack([
        features_from_waveform(recording, corpus.kind, corpus.front_end)
        for recording in tqdm(recordings[corpus.name], desc=f"{corpus.name}: {corpus.front_end}", unit="clip")
    ])  # fmt: skip
    fields = ("features", "intent", "speaker", "split", "clip")
    derived = dataclasses.replace(unheard, features=features, split=np.full(len(unheard), DERIVED_ROOM_TIER))
    joined = {name: np.concatenate([getattr(corpus, name), getattr(derived, name)]) for name in fields}
    return dataclasses.replace(corpus, **joined)


def score_run(run: Run, corpus, test_views, args: argparse.Namespace) -> dict:
    from learning.var.checkpoint import load_var
    from learning.var.evaluate import evaluate_var, nearest_command_accuracy

    path = run_dir(run, args) / "final.pt"
    var = load_var(path, manifest_hash=corpus.manifest_hash, front_end=run.front_end)
    evaluation = evaluate_var(var, test_views, corpus, seed=args.seed)
    train, intents = corpus.subset("train"), len(corpus.intent_names)
    tiers = {
        tier: {
            "nearest_command_accuracy": nearest_command_accuracy(var, train, corpus.subset(tier), intents)[0],
            "triplet_accuracy": evaluation["tiers"][tier]["triplet_accuracy"],
            "clips": evaluation["tiers"][tier]["clips"],
        }
        for tier in unheard_of(corpus)
    }
    return {
        "sounds": run.sounds,
        "front_end": run.front_end,
        "room_copies": run.room_copies,
        "speed_copies": run.speed_copies,
        "voice_copies": run.voice_copies,
        "tiers": tiers,
        "image_to_command": evaluation["image_to_command"],
        "training_seconds": training_seconds(run, args),
    }


def unheard_of(corpus) -> list[str]:
    """The unheard tiers, rooms last."""
    tiers = [split for split in corpus.splits if split != "train"]
    return sorted(tiers, key=lambda tier: tier.startswith(ROOM_TIER))


def main() -> None:
    import torch

    from learning.sounds import load_corpus
    from learning.sounds.build import build_corpora

    args = parse_arguments()
    runs = [Run.parse(text) for text in args.runs.split(",")]
    conditions = Conditions()
    sets = sorted({run.sounds for run in runs} | {TIMED_SET})
    build_corpora(sets, progress=True)
    corpora = {
        (name, fe): load_corpus(name, front_end=fe, progress=True) for name in sets for fe in FRONT_ENDS
    }
    args.corpus_hashes = {name: corpora[name, FRONT_ENDS[0]].manifest_hash for name in sets}
    train_views, test_views = kuka_views(args)
    train_runs(runs, train_views, args)
    torch.set_num_threads(1)  # after the trainings; ms per clip on one core
    recordings: dict[str, list[np.ndarray]] = {}
    scored = {key: with_room_tier(corpus, recordings, args.seed) for key, corpus in corpora.items()}
    result = {
        "benchmark": "voices",
        "world": WORLD,
        "settings": vars(args),
        "runs": {
            run.key: score_run(run, scored[run.sounds, run.front_end], test_views, args) for run in runs
        },
        "frozen": {
            f"{name}:{fe}": score_frozen(scored[name, fe], tuple(unheard_of(scored[name, fe])))
            for name, fe in scored
        },
        "ms_per_clip": {fe: ms_per_clip(fe, corpora[TIMED_SET, fe]) for fe in FRONT_ENDS},
        "measured": time.strftime("%Y-%m-%d %H:%M"),
        **conditions.finish(),
    }
    write_result(Path(args.output), result)
    print_tables(result, args.output)


def print_tables(result: dict, output: str | Path) -> None:
    settings = result["settings"]
    console = Console(width=200)
    for sounds in dict.fromkeys(run["sounds"] for run in result["runs"].values()):
        runs = {key: run for key, run in result["runs"].items() if run["sounds"] == sounds}
        tiers = list(next(iter(runs.values()))["tiers"])
        table = Table(
            title=f"{sounds}: VARs of {settings['steps']} steps on {settings['views']} Kuka views "
            f"({settings['image_size']} px); nearest command / triplet accuracy per unheard tier"
        )
        table.add_column("front end", justify="left")
        for tier in tiers:
            table.add_column(tier.removeprefix("unheard-"), justify="right")
        table.add_column("image → cmd", justify="right")
        table.add_column("train s", justify="right")
        for run in runs.values():
            copies = f", {run['speed_copies']} speed copies" if run.get("speed_copies") else ""
            copies += f", {run['voice_copies']} voice copies" if run.get("voice_copies") else ""
            cells = [f"{run['front_end']}, {run['room_copies']} room copies{copies}"]
            for tier in tiers:
                scores = run["tiers"][tier]
                cells.append(f"{scores['nearest_command_accuracy']:.1%} / {scores['triplet_accuracy']:.1%}")
            cells += [f"{run['image_to_command']:.1%}", f"{run['training_seconds']:.0f}"]
            table.add_row(*cells)
        for front_end in FRONT_ENDS:
            frozen = result["frozen"].get(f"{sounds}:{front_end}")
            if frozen:
                cells = [f"{front_end} frozen, centroids"]
                cells += [f"{frozen[tier]['nearest_command_accuracy']:.1%} / —" for tier in tiers]
                table.add_row(*cells, "—", "—")
        console.print(table)
    for front_end, timings in result["ms_per_clip"].items():
        print(
            f"{front_end}: CPU {timings['cpu_ms_per_corpus_clip']:.1f} ms per Wordset clip, "
            f"{timings['cpu_ms_per_one_second_clip']:.1f} ms per 1 s clip (one thread)"
        )
    print(describe(result))
    print(f"written: {output}")


if __name__ == "__main__":
    main()
