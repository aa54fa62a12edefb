"""Triplet data: images the robot saw with the intent a person would name, and sound draws to make triplets.

On disk (`data_dir()/var/datasets/<name>/`): `images.npy` (uint8 N×H×W×3, memory-mapped), `heard.npy` (int64,
-1 = nothing or several things in view), `meta.json`. The heard id is only used to pick sound clips; the model
never sees it.
"""

import dataclasses
import json
import math
import multiprocessing
import queue
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from core.paths import data_subdir

NOTHING_HEARD = -1
SILENCE_ID = -1  # in drawn sound ids: the all-zero features
CHUNK = 256  # images a worker renders before writing them out and reporting progress
VIEW_KINDS = {"random": "random_views", "block_ends": "block_end_views"}  # what sim.explore renders each with


class DatasetError(ValueError):
    """A triplet dataset that is missing, incomplete or does not match what was asked for."""


def datasets_root() -> Path:
    return data_subdir("var", "datasets")


def dataset_path(name_or_path: str | Path) -> Path:
    """A bare name lives under the data dir; anything with a slash is taken as a path."""
    text = str(name_or_path)
    return Path(text) if ("/" in text or text.startswith(".")) else datasets_root() / text


@dataclass
class ImageDataset:
    path: Path
    images: np.ndarray  # memory-mapped uint8 (N, H, W, 3)
    heard: np.ndarray  # int64 (N,)
    meta: dict[str, Any]

    def __len__(self) -> int:
        return len(self.heard)

    @property
    def image_size(self) -> int:
        return int(self.images.shape[1])

    def read_images(self, indices: np.ndarray) -> np.ndarray:
        """A copy of the images at `indices` (read in sorted order: kind to the page cache)."""
        order = np.argsort(indices, kind="stable")
        batch = np.empty((len(indices), *self.images.shape[1:]), dtype=np.uint8)
        batch[order] = self.images[indices[order]]
        return batch


def open_dataset(name_or_path: str | Path) -> ImageDataset:
    path = dataset_path(name_or_path)
    meta_file = path / "meta.json"
    if not meta_file.is_file():
        raise DatasetError(
            f"No complete triplet dataset at {path} (meta.json missing). Collect it with "
            f"`varbot var collect WORLD --triplets N --name {path.name}`."
        )
    meta = json.loads(meta_file.read_text())
    images = np.load(path / "images.npy", mmap_mode="r")
    heard = np.load(path / "heard.npy")
    if len(images) != len(heard) or len(heard) != meta["count"]:
        raise DatasetError(
            f"{path} is inconsistent: {len(images)} images, {len(heard)} labels, meta says "
            f"{meta['count']}. Collect it again with --overwrite."
        )
    return ImageDataset(path=path, images=images, heard=heard, meta=meta)


# ---------------------------------------------------------------- collection


def _worker_seeds(seed: int, workers: int) -> list[int]:
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(workers)]


def _collect_part(
    path: str,
    world: str,
    start: int,
    count: int,
    seed: int,
    image_size: int,
    domain: Any,
    views: str,
    world_options: dict[str, Any] | None,
    report: Any,
) -> None:
    """Render `count` views of the kind `views` into rows [start, start+count) of the dataset files."""
    try:
        import sim.explore

        render = getattr(sim.explore, VIEW_KINDS[views])

        images = np.load(Path(path) / "images.npy", mmap_mode="r+")
        heard = np.load(Path(path) / "heard.npy", mmap_mode="r+")
        buffer_images = np.empty((CHUNK, image_size, image_size, 3), dtype=np.uint8)
        buffer_heard = np.empty(CHUNK, dtype=np.int64)
        filled, written = 0, start
        rendered = render(
            world, count, seed=seed, image_size=image_size, domain=domain, world_options=world_options
        )
        for image, heard_id, _state in rendered:
            buffer_images[filled] = image
            buffer_heard[filled] = NOTHING_HEARD if heard_id is None else heard_id
            filled += 1
            if filled == CHUNK:
                images[written : written + filled] = buffer_images
                heard[written : written + filled] = buffer_heard
                written += filled
                report.put(("progress", filled))
                filled = 0
        if filled:
            images[written : written + filled] = buffer_images[:filled]
            heard[written : written + filled] = buffer_heard[:filled]
            written += filled
            report.put(("progress", filled))
        images.flush()
        heard.flush()
        if written != start + count:
            raise RuntimeError(f"{views} views: {written - start} rendered, {count} were asked for")
        report.put(("done", None))
    except BaseException:
        report.put(("error", traceback.format_exc()))


def _describe(
    world: str,
    count: int,
    seed: int,
    image_size: int,
    domain: Any,
    views: str = "random",
    world_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    description = {
        "world": world,
        "count": count,
        "seed": seed,
        "image_size": image_size,
        "domain": dataclasses.asdict(domain) if domain is not None else None,
    }
    if views != "random":  # random datasets collected before there was a choice keep matching
        description["views"] = views
    if world_options:  # likewise datasets collected before worlds took options
        description["world_options"] = world_options
    return json.loads(json.dumps(description))  # as it reads back from meta.json (tuples become lists)


def collect_dataset(
    world: str,
    count: int,
    name: str | Path,
    seed: int = 0,
    image_size: int = 96,
    domain: Any = None,
    workers: int = 2,
    overwrite: bool = False,
    progress: bool = True,
    views: str = "random",
    world_options: dict[str, Any] | None = None,
) -> ImageDataset:
    """Let the robot move at random in `world` and store `count` views, each with what a person would say;
    `views="block_ends"`: with the gripper placed around a block's end instead (`sim.explore`, arm worlds).
    `world_options` go to the world's constructor, e.g. `{"heard_reach_m": 0.35}` for the TurtleBot.

    Work is split over `workers` spawned processes (each its own seed) writing straight into the memory-mapped
    files. An identical complete dataset is reused; a different one is only replaced with `overwrite`.
    """
    from sim import WORLDS

    if world not in WORLDS:
        raise DatasetError(f"Unknown world '{world}'; choose one of {sorted(WORLDS)}.")
    if count <= 0:
        raise DatasetError(f"--triplets must be positive, got {count}.")
    if views not in VIEW_KINDS:
        raise DatasetError(f"views must be one of {', '.join(VIEW_KINDS)}, got {views!r}.")
    if world_options:
        _check_world_options(world, world_options)
    path = dataset_path(name)
    wanted = _describe(world, count, seed, image_size, domain, views, world_options)
    if (path / "meta.json").is_file():
        existing = json.loads((path / "meta.json").read_text())
        same_kind = existing.get("views", "random") == views
        same_kind &= existing.get("world_options") == wanted.get("world_options")
        if same_kind and all(existing.get(key) == value for key, value in wanted.items()) and not overwrite:
            return open_dataset(path)
        if not overwrite:
            raise DatasetError(
                f"{path} already holds a different dataset ({existing['world']}, "
                f"{existing['count']} views); pass --overwrite or choose another --name."
            )
    path.mkdir(parents=True, exist_ok=True)
    (path / "meta.json").unlink(missing_ok=True)
    np.lib.format.open_memmap(path / "images.npy", "w+", np.uint8, (count, image_size, image_size, 3)).flush()
    np.lib.format.open_memmap(path / "heard.npy", "w+", np.int64, (count,)).flush()

    workers = max(1, min(workers, math.ceil(count / CHUNK)))
    sizes = [count // workers + (1 if i < count % workers else 0) for i in range(workers)]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).tolist()
    started = time.perf_counter()
    seeds = _worker_seeds(seed, workers)
    _run_workers(path, world, starts, sizes, seeds, image_size, domain, views, world_options, progress)
    elapsed = time.perf_counter() - started

    heard = np.load(path / "heard.npy")
    wanted.update(
        workers=workers,
        collection_seconds=round(elapsed, 2),
        views_per_second=round(count / elapsed, 1),
        heard_counts={str(k): int((heard == k).sum()) for k in sorted(set(heard.tolist()))},
    )
    (path / "meta.json").write_text(json.dumps(wanted, indent=2))
    return open_dataset(path)


def _check_world_options(world: str, world_options: dict[str, Any]) -> None:
    """Build the world once with the options, so a wrong one fails here and not in every worker."""
    import gymnasium as gym

    from sim import world_id

    try:
        gym.make(world_id(world), image_size=16, **world_options).close()
    except (TypeError, ValueError) as error:
        raise DatasetError(f"The {world} world refuses the options {world_options}: {error}") from error


def _run_workers(
    path: Path,
    world: str,
    starts: list[int],
    sizes: list[int],
    seeds: list[int],
    image_size: int,
    domain: Any,
    views: str,
    world_options: dict[str, Any] | None,
    progress: bool,
) -> None:
    if len(sizes) == 1:  # no process to spawn: render here (small datasets, tests)
        report: Any = queue.SimpleQueue()
        _collect_part(
            str(path), world, starts[0], sizes[0], seeds[0], image_size, domain, views, world_options, report
        )
        _drain(report, [None], sum(sizes), progress, world)
        return
    context = multiprocessing.get_context("spawn")  # never fork a process that may hold torch threads
    report = context.Queue()
    processes = [
        context.Process(
            target=_collect_part,
            args=(str(path), world, start, size, seed, image_size, domain, views, world_options, report),
            daemon=True,
        )
        for start, size, seed in zip(starts, sizes, seeds, strict=True)
    ]
    for process in processes:
        process.start()
    try:
        _drain(report, processes, sum(sizes), progress, world)
    finally:
        for process in processes:
            if process.is_alive():
                process.terminate()
            process.join()


def _drain(report: Any, processes: list[Any], total: int, progress: bool, world: str) -> None:
    pending = len(processes)
    with tqdm(total=total, desc=f"collect {world}", unit="view", disable=not progress) as bar:
        while pending:
            try:
                kind, value = report.get(timeout=5.0)
            except queue.Empty:
                dead = [p for p in processes if p is not None and p.exitcode not in (None, 0)]
                if dead:
                    raise RuntimeError(f"a collection worker died (exit code {dead[0].exitcode})") from None
                continue
            if kind == "progress":
                bar.update(value)
            elif kind == "done":
                pending -= 1
            else:
                raise RuntimeError(f"a collection worker failed:\n{value}")


# ---------------------------------------------------------------- sounds for triplets


@dataclass
class SoundBank:
    """Clips grouped by intent so that a clip of intent k can be drawn for a whole batch at once."""

    features: np.ndarray  # (M, frames, values) float32 features of the corpus's front end, sorted by intent
    intent: np.ndarray  # (M,)
    starts: np.ndarray  # (K,) first row of each intent
    counts: np.ndarray  # (K,)

    @classmethod
    def build(cls, features: np.ndarray, intent: np.ndarray, num_intents: int) -> "SoundBank":
        order = np.argsort(intent, kind="stable")
        intent = intent[order]
        counts = np.bincount(intent, minlength=num_intents)[:num_intents]
        if (counts == 0).any():
            missing = np.flatnonzero(counts == 0).tolist()
            raise DatasetError(
                f"The sound selection has no clip for intent(s) {missing}; every intent needs one."
            )
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        return cls(np.ascontiguousarray(features[order], dtype=np.float32), intent, starts, counts)

    @classmethod
    def from_corpus(
        cls,
        corpus: Any,
        splits: str | list[str] | tuple[str, ...] = ("train",),
        speakers: list[str] | tuple[str, ...] | None = None,
        speed_copies: int = 0,
        speed_range: tuple[float, float] = (0.85, 1.15),
        seed: int = 0,
        room_copies: int = 0,
        voice_copies: int = 0,
        voice_range: tuple[float, float] = (0.85, 1.15),
    ) -> "SoundBank":
        """The clips of these splits (and speakers), plus `speed_copies` re-renderings of each, played faster
        or slower (tempo, pitch and formants together), and `voice_copies` with only the formants moved (a
        longer or shorter vocal tract at the same pitch and tempo), for voices training never heard, and
        `room_copies` recordings of each in simulated rooms (reverberation, noise, a cheap microphone:
        learning.room_acoustics), for rooms it never heard. Speed and voice copies are refused for sets
        whose commands may be pitches or timbres (notes)."""
        chosen = corpus.subset(list(splits) if not isinstance(splits, str) else splits)
        if speakers:
            chosen = chosen.by_speakers(speakers)
            if not len(chosen.intent):
                raise DatasetError(f"No clip by speaker(s) {list(speakers)} in splits {splits}.")
        features, intent = chosen.features, chosen.intent
        if (speed_copies or voice_copies) and corpus.kind not in ("speech", "phrase"):
            raise DatasetError(
                f"Speed and voice copies change pitch or timbre, and {corpus.name} is a '{corpus.kind}' "
                "set whose commands may be pitches or timbres: train it without --speed-copies and "
                "--voice-copies."
            )
        for perturbation, count, factors in (
            ("speed", speed_copies, speed_range),
            ("voice", voice_copies, voice_range),
        ):
            if count:
                copies = perturbed_features(
                    chosen.clip, corpus.kind, count, perturbation, factors, seed, corpus.front_end
                )
                features = np.concatenate([features, copies])
                intent = np.concatenate([intent, np.repeat(chosen.intent, count)])
        if room_copies:
            copies = room_recorded_features(chosen.clip, corpus.kind, room_copies, seed, corpus.front_end)
            features = np.concatenate([features, copies])
            intent = np.concatenate([intent, np.repeat(chosen.intent, room_copies)])
        return cls.build(features, intent, len(corpus.intent_names))

    @property
    def num_intents(self) -> int:
        return len(self.counts)

    def draw(self, sound_ids: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One clip per id (intent k, or SILENCE_ID for the all-zero features)."""
        out = np.zeros((len(sound_ids), *self.features.shape[1:]), dtype=np.float32)
        spoken = sound_ids >= 0
        ids = sound_ids[spoken]
        rows = self.starts[ids] + (rng.random(len(ids)) * self.counts[ids]).astype(np.int64)
        out[spoken] = self.features[rows]
        return out


# Voice copies draw their warps from a stream apart from the speed copies' (whose seed is the run's)
VOICE_COPY_STREAM = 5


def perturbed_features(
    paths: np.ndarray,
    kind: str,
    copies: int,
    perturbation: str,
    factors: tuple[float, float],
    seed: int,
    front_end: str = "mfcc",
) -> np.ndarray:
    """Features of `copies` renderings of every clip, clip by clip (rows c·copies..), each with a factor drawn
    from `factors`: "speed" plays it faster or slower (tempo, pitch and formants together), "voice" moves
    its formants only (learning.augment's vocal tract warp: pitch and tempo kept)."""
    import torch

    from learning.augment import perturb_speed, warp_vocal_tract

    if perturbation == "speed":
        generator = torch.Generator().manual_seed(seed)
    elif perturbation == "voice":
        generator = torch.Generator().manual_seed(seed * 1_000 + VOICE_COPY_STREAM)
    else:
        raise ValueError(f"Unknown perturbation {perturbation!r}: use speed or voice.")

    def renderings(waveform: np.ndarray) -> list[np.ndarray]:
        if perturbation == "voice":
            rows = torch.from_numpy(np.ascontiguousarray(waveform)).repeat(copies, 1)
            return list(warp_vocal_tract(rows, generator, factors).numpy())
        slowed_length = math.ceil(len(waveform) / min(factors[0], 1.0)) + 1  # room for the slowest copy
        padded = np.pad(waveform, (0, slowed_length - len(waveform)))
        return list(perturb_speed(torch.from_numpy(padded).repeat(copies, 1), generator, factors).numpy())

    description = f"{perturbation} copies ×{copies}"
    return _features_of_copies(paths, kind, (front_end,), renderings, description)[front_end]


# Room copies draw their rooms from this stream, apart from the corpora's unheard-room tiers' streams.
ROOM_COPY_STREAM = 3


def room_recorded_features(
    paths: np.ndarray, kind: str, copies: int, seed: int, front_end: str = "mfcc"
) -> np.ndarray:
    """Features of `copies` recordings of every clip in simulated rooms, clip by clip (rows c·copies..)."""
    return room_recorded_features_in(paths, kind, copies, seed, (front_end,))[front_end]


def room_recorded_features_in(
    paths: np.ndarray, kind: str, copies: int, seed: int, front_ends: Sequence[str]
) -> dict[str, np.ndarray]:
    """`room_recorded_features` for several front ends at once: each room recording is made once and read
    by every front end (the rooms, drawn in the same order, are those of a call with one front end)."""
    from learning.room_acoustics import record_in_room

    rng = np.random.default_rng([seed, ROOM_COPY_STREAM])

    def room_copies(waveform: np.ndarray) -> list[np.ndarray]:
        return [record_in_room(waveform, rng) for _ in range(copies)]

    return _features_of_copies(paths, kind, front_ends, room_copies, f"room copies ×{copies}")


def _features_of_copies(
    paths: np.ndarray,
    kind: str,
    front_ends: Sequence[str],
    copies_of: Callable[[np.ndarray], list[np.ndarray]],
    description: str,
) -> dict[str, np.ndarray]:
    """{front end: features of the waveforms `copies_of` makes from every clip, in clip order}."""
    from learning.audio import decode_audio, feature_shape, features_from_waveform

    rows: dict[str, list[np.ndarray]] = {name: [] for name in front_ends}
    for path in tqdm(paths, desc=description, unit="clip", leave=False):
        waveform, _ = decode_audio(Path(path).read_bytes())
        for copy in copies_of(waveform):
            for name in front_ends:
                rows[name].append(features_from_waveform(copy, kind, name))
    return {
        name: np.stack(found) if found else np.zeros((0, *feature_shape(kind, name)), np.float32)
        for name, found in rows.items()
    }


def triplet_sound_ids(heard: np.ndarray, num_intents: int, rng: np.random.Generator):
    """Positive and negative sound ids for images with these heard ids.

    Target in view (k): positive = a clip of k; negative = uniformly one of the other intents or silence.
    Nothing in view: positive = silence; negative = a clip of any intent.
    """
    positive = np.where(heard >= 0, heard, SILENCE_ID)
    draw = rng.integers(0, num_intents, size=len(heard))
    shifted = np.where(draw >= heard, draw + 1, draw)  # skip k itself; value num_intents means silence
    negative = np.where(heard >= 0, np.where(shifted == num_intents, SILENCE_ID, shifted), draw)
    return positive, negative


def draw_triplet_sounds(heard: np.ndarray, bank: SoundBank, rng: np.random.Generator):
    positive_ids, negative_ids = triplet_sound_ids(heard, bank.num_intents, rng)
    return bank.draw(positive_ids, rng), bank.draw(negative_ids, rng)


def write_dataset(name: str | Path, images: np.ndarray, heard: np.ndarray, **meta: Any) -> ImageDataset:
    """Store images someone already has (e.g. snapshots from the robot) as a triplet dataset."""
    images = np.asarray(images)
    heard = np.asarray(heard, dtype=np.int64)
    if (
        images.dtype != np.uint8
        or images.ndim != 4
        or images.shape[3] != 3
        or images.shape[1] != images.shape[2]
    ):
        raise DatasetError(f"images must be uint8 (N, S, S, 3), got {images.dtype} {images.shape}.")
    if len(images) != len(heard):
        raise DatasetError(f"{len(images)} images but {len(heard)} heard ids.")
    path = dataset_path(name)
    path.mkdir(parents=True, exist_ok=True)
    (path / "meta.json").unlink(missing_ok=True)
    np.save(path / "images.npy", images)
    np.save(path / "heard.npy", heard)
    meta = {
        "world": None,
        "seed": None,
        "domain": None,
        **meta,
        "count": len(heard),
        "image_size": images.shape[1],
    }
    (path / "meta.json").write_text(json.dumps(meta, indent=2))
    return open_dataset(path)
