"""Replay for the household VAR fine-tune, so that it keeps what it knew: views of the simulated training
room rendered fresh (`sim.explore.random_views`, no domain shift) paired with clips of the corpus the parent
VAR learnt from (its checkpoint's `sound_set`), by the pre-training's own rule (`triplet_sound_ids`: the
simulator says what is in view, as it does for the base world's training data). They join the household's
training triplets as `fraction` of them (`varbot var finetune` mixes 25 %); the held-out triplets stay the
household's own. Nothing large ships: the views are rendered by the worker, the clips are the corpus's.

In a world with blocks, `block_ends_share` of the replayed views have the gripper placed around a block's end
(`sim.explore.block_end_views`, labelled by the ray), what the base was taught by `varbot models block-ends`,
so that the fine-tune keeps where a block ends. A world without blocks replays random views only."""

from dataclasses import replace
from pathlib import Path

import numpy as np

from worker.household import REPLAYED_VIEW, SILENCE_ROW, HouseholdData


class ReplayMissing(RuntimeError):
    """The replay world or corpus is missing; the message says what to do."""


def with_replay(
    data: HouseholdData,
    parent_var: Path,
    world: str,
    fraction: float,
    seed: int,
    block_ends_share: float = 0.0,
) -> tuple[HouseholdData, int]:
    """`data` plus replay triplets making up `fraction` of its training triplets, and how many were added."""
    if fraction <= 0:
        return data, 0
    count = round(len(data.train_triplets) * fraction / (1 - fraction))
    if count == 0:
        return data, 0
    corpus = _parent_corpus(parent_var)
    images, heard = replay_views(world, count, data.images.shape[1], seed, block_ends_share)
    return joined_with_replay(data, corpus, images, heard, np.random.default_rng([seed, 41])), count


def _parent_corpus(parent_var: Path):  # type: ignore[no-untyped-def]
    from learning.sounds import load_corpus
    from learning.var.checkpoint import front_end_of, read_checkpoint

    sound_set = read_checkpoint(parent_var).get("sound_set")
    if not sound_set:
        raise ReplayMissing(
            "the model being fine-tuned names no sound corpus to replay (it was not trained on one): "
            "fine-tune it without replay (run parameter replay_fraction 0), or start from a base model "
            "built with `varbot models build-base`"
        )
    try:
        try:
            corpus = load_corpus(sound_set, front_end=front_end_of(parent_var))
        except FileNotFoundError:
            _build_missing_corpus(sound_set)
            corpus = load_corpus(sound_set, front_end=front_end_of(parent_var))
        corpus = corpus.subset("train")
    except (FileNotFoundError, ValueError, RuntimeError) as missing:
        raise ReplayMissing(
            f"the replay corpus {sound_set!r} of the model being fine-tuned is missing on this worker and "
            f"could not be built here ({missing}); build it with `varbot sounds build --sets {sound_set}` "
            "(it needs the speech synthesizers in scripts/install-system-packages.sh), or fine-tune "
            "without replay (run parameter replay_fraction 0)"
        ) from missing
    return corpus


def _build_missing_corpus(sound_set: str) -> None:
    """A worker that never built the base corpus builds it once, as `varbot sounds build` would (offline,
    from the speech synthesizers; about half a minute for a speech set on this 2-core machine)."""
    from learning.sounds.build import build_corpora

    build_corpora([sound_set], progress=False, log=lambda line: None)


def replay_views(
    world: str, count: int, image_size: int, seed: int, block_ends_share: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """`count` views of the training room and what the simulator says is in each (-1: nothing): random
    views, then, in a world with blocks, `block_ends_share` of them placed around a block's end."""
    from sim import has_blocks
    from sim.explore import block_end_views, random_views

    try:
        placed = round(count * block_ends_share) if has_blocks(world) else 0
        views = list(random_views(world, count - placed, seed=seed + 4099, image_size=image_size))
        if placed:
            views += list(block_end_views(world, placed, seed=seed + 8191, image_size=image_size))
    except Exception as error:  # an unknown world, or PyBullet assets missing on this worker
        raise ReplayMissing(
            f"the simulated training room of the {world} world cannot be rendered on this worker ({error}); "
            "install the simulator here, or fine-tune without replay (run parameter replay_fraction 0)"
        ) from error
    heard = np.array([-1 if h is None else int(h) for _, h, _ in views], dtype=np.int64)
    return np.stack([image for image, _, _ in views]).astype(np.uint8), heard


def joined_with_replay(  # type: ignore[no-untyped-def]
    data: HouseholdData, corpus, images: np.ndarray, heard: np.ndarray, rng: np.random.Generator
):
    from learning.var.dataset import triplet_sound_ids

    if corpus.features.shape[1:] != data.features.shape[1:]:
        raise ReplayMissing(
            f"the replay corpus {corpus.name!r} gives features shaped {corpus.features.shape[1:]}, the "
            f"household's clips {data.features.shape[1:]}; rebuild the corpus for this model's front end"
        )
    positive, negative = triplet_sound_ids(heard, len(corpus.intent_names), rng)
    by_intent = [np.flatnonzero(corpus.intent == k) for k in range(len(corpus.intent_names))]
    chosen: list[int] = []  # corpus rows, appended after the household's clips

    def clip_row(sound_id: int) -> int:
        if sound_id < 0:
            return SILENCE_ROW
        chosen.append(int(rng.choice(by_intent[sound_id])))
        return len(data.features) + len(chosen) - 1

    first_image = len(data.images)
    pairs = zip(positive.tolist(), negative.tolist(), strict=True)
    triplets = np.array(
        [(first_image + i, clip_row(p), clip_row(n)) for i, (p, n) in enumerate(pairs)], dtype=np.int64
    ).reshape(-1, 3)
    rows = np.array(chosen, dtype=np.int64)
    return replace(
        data,
        snapshot_ids=np.concatenate([data.snapshot_ids, np.full(len(images), REPLAYED_VIEW)]),
        images=np.concatenate([data.images, images]),
        sim_heard=np.concatenate([data.sim_heard, heard]),
        clip_ids=np.concatenate([data.clip_ids, np.full(len(rows), -1)]),
        features=np.concatenate([data.features, corpus.features[rows].astype(np.float32)]),
        clip_intent=np.concatenate([data.clip_intent, corpus.intent[rows]]),
        triplets=np.concatenate([data.triplets, triplets]),
        held_out=np.concatenate([data.held_out, np.zeros(len(triplets), dtype=bool)]),
    )
