"""Sound corpora benchmark: build time and size, features per second, and a speaker-separation sanity check.

The sanity check trains a tiny CNN (intent from MFCC) on each set's `train` split only and reports accuracy on
every unheard tier: if the splits were leaky (a speaker in two splits), unheard accuracy would equal train's.

    .venv/bin/python bench/sounds.py            # default corpus (wordset, objects, notes, mix), fresh build
    .venv/bin/python bench/sounds.py --all-sets # also the two phrase sets
Writes bench/results/sounds.json.
"""

import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import typer
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table
from torch import nn
from tqdm import tqdm

from core.paths import data_dir
from learning.audio import features_from_bytes
from learning.augment import augment_features
from learning.sounds import DEFAULT_SETS, SET_NAMES, SoundCorpus, load_corpus
from learning.sounds.build import build_corpora

RESULTS = Path(__file__).resolve().parent / "results" / "sounds.json"


class TinyIntentCNN(nn.Module):
    def __init__(self, intents: int = 4) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Conv2d(1, 8, 3, padding=1), nn.BatchNorm2d(8), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(8, 16, 3, padding=1), nn.BatchNorm2d(16), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(16, 32, 3, padding=1), nn.BatchNorm2d(32), nn.ReLU(), nn.AdaptiveAvgPool2d(1),
            nn.Flatten(), nn.Dropout(0.2), nn.Linear(32, intents),
        )  # fmt: skip

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.layers(features[:, None])


def main(
    all_sets: Annotated[
        bool, typer.Option("--all-sets", help="Also build and check the phrase sets.")
    ] = False,
    epochs: Annotated[int, typer.Option(help="Classifier epochs per set.")] = 8,
    seed: int = 0,
    threads: Annotated[int, typer.Option(help="torch threads for the classifier.")] = 2,
    root: Annotated[
        Path | None,
        typer.Option(
            help="Reuse corpora built under this root (build times then come from their build.json)."
        ),
    ] = None,
) -> None:
    console = Console()
    sets = list(SET_NAMES if all_sets else DEFAULT_SETS)
    keep = root is not None
    root = root or Path(tempfile.mkdtemp(prefix="bench-sounds-", dir=data_dir()))
    conditions = Conditions()
    try:
        torch.set_num_threads(1)  # the build: parallel renderer threads, tiny MFCC ops
        started = time.perf_counter()
        built = build_corpora(sets, profile="default", seed=seed, root=root, workers=2)
        per_set = {r.name: r.seconds if not r.cached else _recorded_build_seconds(r.folder) for r in built}
        build_s = time.perf_counter() - started if not keep else sum(per_set.values())
        corpora = {name: load_corpus(name, root) for name in sets}
        build = _build_summary(root, corpora, build_s, per_set)
        features_per_s = _features_per_second(corpora)
        torch.set_num_threads(threads)  # only now: no renderer runs any more
        sanity = {name: _sanity_check(corpus, epochs, seed) for name, corpus in corpora.items()}
    finally:
        if not keep:
            shutil.rmtree(root, ignore_errors=True)
    result = {
        **conditions.finish(),
        "seed": seed,
        "build": build,
        "features_per_second": features_per_s,
        "sanity_accuracy": sanity,
        "classifier": f"TinyIntentCNN (3 conv), {epochs} epochs, Adam 1e-3, batch 64, feature augmentation",
    }
    write_result(RESULTS, result)
    _print(console, result)


def _build_summary(
    root: Path, corpora: dict[str, SoundCorpus], seconds: float, per_set: dict[str, float]
) -> dict[str, object]:
    sets = {}
    speakers: set[str] = set()
    for name, corpus in corpora.items():
        folder = root / "sounds" / name
        splits, counts = np.unique(corpus.split, return_counts=True)
        sets[name] = {
            "clips": len(corpus),
            "speakers": len(set(corpus.speaker.tolist())),
            "clips_per_split": dict(zip(splits.tolist(), counts.tolist(), strict=True)),
            "speakers_per_split": {s: len(set(corpus.speaker[corpus.split == s].tolist())) for s in splits},
            "size_mb": round(sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6, 1),
            "build_s": round(per_set.get(name, 0.0), 1),
        }
        if name != "notes":
            speakers |= set(corpus.speaker.tolist())
    return {
        "seconds": round(seconds, 1),
        "clips": sum(s["clips"] for s in sets.values()),
        "size_mb": round(sum(s["size_mb"] for s in sets.values()), 1),
        "speech_speakers": len(speakers),
        "sets": sets,
    }


def _recorded_build_seconds(folder: Path) -> float:
    return float(json.loads((folder / "build.json").read_text())["build_seconds"])


def _features_per_second(corpora: dict[str, SoundCorpus], count: int = 300) -> dict[str, float]:
    rates = {}
    for name, corpus in corpora.items():
        clips = [Path(p).read_bytes() for p in corpus.clip[:: max(1, len(corpus) // count)][:count]]
        started = time.perf_counter()
        for data in clips:
            features_from_bytes(data, corpus.kind)
        rates[f"{name} ({corpus.kind})"] = round(len(clips) / (time.perf_counter() - started), 1)
    return rates


def _sanity_check(corpus: SoundCorpus, epochs: int, seed: int) -> dict[str, float]:
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    train = corpus.subset("train")
    features = torch.from_numpy(train.features)
    mean = features.mean(dim=(0, 1))
    std = features.std(dim=(0, 1)).clamp(min=1e-3)
    labels = torch.from_numpy(train.intent)
    model = TinyIntentCNN()
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in tqdm(range(epochs), desc=f"sanity {corpus.name}", unit="epoch"):
        model.train()
        order = torch.randperm(len(labels), generator=generator)
        for batch in order.split(64):
            augmented = augment_features(features[batch], generator)
            loss = nn.functional.cross_entropy(model((augmented - mean) / std), labels[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    model.eval()
    accuracy = {}
    with torch.no_grad():
        for split in corpus.splits:
            part = corpus.subset(split)
            predicted = model((torch.from_numpy(part.features) - mean) / std).argmax(dim=1).numpy()
            accuracy[split] = round(float((predicted == part.intent).mean()), 3)
    return accuracy


def _print(console: Console, result: dict) -> None:
    build = result["build"]
    table = Table(
        title=f"Sound corpora: built in {build['seconds']} s, {build['clips']} clips, {build['size_mb']} MB"
    )
    for column in ("set", "clips", "speakers", "clips per split", "build s", "MB", "features/s"):
        table.add_column(column)
    rates = {k.split(" ")[0]: v for k, v in result["features_per_second"].items()}
    for name, s in build["sets"].items():
        per_split = ", ".join(f"{k} {v}" for k, v in s["clips_per_split"].items())
        cells = (s["clips"], s["speakers"], per_split, s["build_s"], s["size_mb"], rates[name])
        table.add_row(name, *map(str, cells))
    console.print(table)
    sanity = Table(title="Speaker-separation sanity check: intent accuracy of a tiny CNN trained on `train`")
    sanity.add_column("set")
    tiers = sorted({t for acc in result["sanity_accuracy"].values() for t in acc}, key=lambda t: t != "train")
    for tier in tiers:
        sanity.add_column(tier)
    for name, accuracy in result["sanity_accuracy"].items():
        sanity.add_row(name, *[f"{accuracy[t]:.3f}" if t in accuracy else "" for t in tiers])
    console.print(sanity)
    console.print(describe(result))
    console.print(f"written {RESULTS}")


if __name__ == "__main__":
    typer.run(main)
