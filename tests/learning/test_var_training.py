"""VAR training end to end on real simulated views and a real (small) sound corpus: tiny images, seconds."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from learning.sounds import load_corpus
from learning.sounds.build import build_corpora
from learning.var.checkpoint import CheckpointMismatchError, load_var, read_checkpoint
from learning.var.dataset import (
    DatasetError,
    SoundBank,
    collect_dataset,
    perturbed_features,
)
from learning.var.evaluate import embed_images, evaluate_var, nearest_command_accuracy, triplet_accuracy
from learning.var.finetune import finetune_config
from learning.var.train import TrainConfig, train
from sim.domain import DomainShift

SIZE = 40
VIEWS = 1500
NEW_VOICE = "unheard-real-voices"


@pytest.fixture(scope="module")
def wordset():
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    return load_corpus("wordset")


@pytest.fixture(scope="module")
def kuka_views():
    return collect_dataset(
        "kuka", VIEWS, "test-var-kuka-train", seed=0, image_size=SIZE, workers=2, progress=False
    )


@pytest.fixture(scope="module")
def kuka_test_views():
    return collect_dataset(
        "kuka", 600, "test-var-kuka-test", seed=1, image_size=SIZE, workers=2, progress=False
    )


def tiny_config(run_dir: Path, **overrides) -> TrainConfig:
    settings = dict(
        dataset="test-var-kuka-train",
        sounds="wordset",
        run_dir=str(run_dir),
        max_steps=250,
        batch_size=64,
        lr=3e-3,
        warmup_steps=10,
        log_every_steps=5,
        checkpoint_every_steps=10,
        threads=1,  # on a busy 2-core machine one thread is several times faster than two
        progress=False,
    )
    settings.update(overrides)
    return TrainConfig(**settings)


@pytest.fixture(scope="module")
def pretrained(wordset, kuka_views, tmp_path_factory):
    return train(tiny_config(tmp_path_factory.mktemp("pretrain")))


def test_tiny_run_reaches_triplet_accuracy_far_above_chance_on_unheard_voices(
    pretrained, wordset, kuka_test_views
):
    """Unheard voices, views from another seed. 1,500 views hold only ~15 block layouts, too few to learn
    *which* block is under the gripper in a new layout (bench/var.py measures that on 50,000 views); what a
    tiny run must learn is to tell views with a target under the gripper from views with none."""
    var = load_var(pretrained.checkpoint, manifest_hash=wordset.manifest_hash)
    scores = evaluate_var(var, kuka_test_views, wordset)
    assert set(scores["tiers"]) == {"train", "unheard-easy", NEW_VOICE}
    for tier in ("unheard-easy", NEW_VOICE):
        assert scores["tiers"][tier]["triplet_accuracy"] > 0.85, scores  # chance: 0.5
        assert scores["tiers"][tier]["triplet_accuracy_nothing_in_view"] > 0.9, scores
    records = [json.loads(line) for line in (pretrained.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert {"train", "val"} <= {r["kind"] for r in records}
    assert (pretrained.run_dir / "metrics.png").stat().st_size > 0


def test_a_resumed_run_ends_where_an_uninterrupted_one_does(wordset, kuka_views, tmp_path):
    straight = train(tiny_config(tmp_path / "straight", max_steps=20, eval_every_steps=10))
    interrupted = train(
        tiny_config(tmp_path / "resumed", max_steps=20, eval_every_steps=10),
        callback=lambda record: record["step"] >= 10,
    )
    assert interrupted.interrupted and interrupted.steps == 10
    resumed = train(tiny_config(tmp_path / "resumed", max_steps=20, eval_every_steps=10))
    assert resumed.steps == 20 and not resumed.interrupted
    first, second = read_checkpoint(straight.checkpoint), read_checkpoint(resumed.checkpoint)
    for name, tensor in first["state_dict"].items():
        torch.testing.assert_close(second["state_dict"][name], tensor, msg=name)
    steps = [
        json.loads(line)["step"] for line in (tmp_path / "resumed" / "metrics.jsonl").read_text().splitlines()
    ]
    assert steps == [
        json.loads(line)["step"]
        for line in (tmp_path / "straight" / "metrics.jsonl").read_text().splitlines()
    ]


def test_resuming_with_other_settings_is_refused(wordset, kuka_views, tmp_path):
    train(tiny_config(tmp_path, max_steps=2))
    with pytest.raises(CheckpointMismatchError, match="batch_size"):
        train(tiny_config(tmp_path, max_steps=4, batch_size=32))


def test_early_stopping_ends_a_run_once_held_out_accuracy_stops_improving(wordset, kuka_views, tmp_path):
    result = train(tiny_config(tmp_path, lr=1e-5, patience=2, eval_every_steps=2, max_steps=200))
    assert result.stopped_early and result.steps < 200
    scores = [
        json.loads(line)["val_balanced_accuracy"]
        for line in (tmp_path / "metrics.jsonl").read_text().splitlines()
        if '"val"' in line
    ]
    assert max(scores[-2:]) <= max(scores[:-2]) == result.best_val_accuracy  # the last two were no better
    best = load_var(tmp_path / "best.pt")
    final = load_var(result.checkpoint)  # early stopping hands back the best weights, not the last
    for name, tensor in best.state_dict().items():
        torch.testing.assert_close(final.state_dict()[name], tensor)


def _new_voice_accuracy(checkpoint: Path, views, corpus) -> dict[str, float]:
    var = load_var(checkpoint)
    clips = corpus.subset(NEW_VOICE)
    bank = SoundBank.build(clips.features, clips.intent, len(corpus.intent_names))
    return triplet_accuracy(embed_images(var, views.images), views.heard, var, bank, seed=0, repeats=4)


def test_fine_tuning_in_a_new_room_with_a_new_voice_raises_accuracy_there(pretrained, wordset, tmp_path):
    shifted = DomainShift.unseen_room()
    collect_dataset(
        "kuka", 600, "test-var-new-room", seed=5, image_size=SIZE, domain=shifted, workers=2, progress=False
    )
    new_room_test = collect_dataset(
        "kuka",
        300,
        "test-var-new-room-test",
        seed=6,
        image_size=SIZE,
        domain=shifted,
        workers=1,
        progress=False,
    )
    before = _new_voice_accuracy(pretrained.checkpoint, new_room_test, wordset)
    config = finetune_config(
        pretrained.checkpoint,
        "test-var-new-room",
        "wordset",
        tmp_path,
        sound_splits=(NEW_VOICE,),
        replay_dataset="test-var-kuka-train",
        epochs=15,
        lr=2e-3,
        batch_size=64,
        threads=1,
        progress=False,
    )
    result = train(config)
    after = _new_voice_accuracy(result.checkpoint, new_room_test, wordset)
    assert after["triplet_accuracy_in_view"] > before["triplet_accuracy_in_view"] + 0.05, (before, after)
    records = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert any("replay_val_accuracy" in r for r in records)  # the original triplets were mixed in and checked


def test_fine_tuning_refuses_a_checkpoint_for_another_image_size(pretrained, wordset, tmp_path):
    collect_dataset("kuka", 60, "test-var-kuka-48px", seed=7, image_size=48, workers=1, progress=False)
    config = finetune_config(pretrained.checkpoint, "test-var-kuka-48px", "wordset", tmp_path, progress=False)
    with pytest.raises(CheckpointMismatchError, match=f"image_size: model has 48, checkpoint has {SIZE}"):
        train(config)


def test_collected_views_are_stored_as_memory_mapped_uint8_with_heard_ids(kuka_views):
    assert isinstance(kuka_views.images, np.memmap) and kuka_views.images.dtype == np.uint8
    assert kuka_views.images.shape == (VIEWS, SIZE, SIZE, 3)
    assert set(np.unique(kuka_views.heard)) <= {-1, 0, 1, 2, 3}
    assert (kuka_views.heard >= 0).mean() > 0.1 and (kuka_views.heard == -1).any()
    assert kuka_views.images.reshape(VIEWS, -1).std(axis=1).min() > 0  # every row was rendered
    assert kuka_views.meta["workers"] == 2 and kuka_views.meta["world"] == "kuka"


def test_an_identical_collection_is_reused_and_a_different_one_refused(kuka_test_views):
    again = collect_dataset(
        "kuka", 600, "test-var-kuka-test", seed=1, image_size=SIZE, workers=2, progress=False
    )
    np.testing.assert_array_equal(again.heard, kuka_test_views.heard)
    with pytest.raises(ValueError, match="--overwrite"):
        collect_dataset("kuka", 300, "test-var-kuka-test", seed=2, image_size=SIZE, workers=1, progress=False)


def test_views_around_the_blocks_ends_are_collected_alike_and_never_taken_for_random_ones(kuka_test_views):
    """The same workers render them; about half show the gripper over a block (random ones: about one in
    nine), and a collection under the same name and seed asking for random views is refused."""
    ends = collect_dataset(
        "kuka",
        300,
        "test-var-kuka-ends",
        seed=1,
        image_size=SIZE,
        workers=2,
        progress=False,
        views="block_ends",
    )
    assert ends.meta["views"] == "block_ends" and "views" not in kuka_test_views.meta
    over_a_block = (ends.heard >= 0).mean()
    assert 0.3 < over_a_block < 0.75 and over_a_block > 2 * (kuka_test_views.heard >= 0).mean()
    with pytest.raises(DatasetError, match="--overwrite"):
        collect_dataset("kuka", 300, "test-var-kuka-ends", seed=1, image_size=SIZE, workers=1, progress=False)
    with pytest.raises(DatasetError, match="views must be one of random, block_ends"):
        collect_dataset("kuka", 10, "test-var-kuka-anywhere", image_size=SIZE, views="anywhere")


def test_a_tighter_heard_reach_names_fewer_of_the_same_views_and_is_its_own_dataset():
    """World options reach the world in every worker: the robot wanders the same way, but only views from
    close by are named after an object."""
    wide = collect_dataset("turtlebot", 300, "test-var-tb-wide", seed=3, image_size=SIZE, progress=False)
    tight = collect_dataset(
        "turtlebot",
        300,
        "test-var-tb-tight",
        seed=3,
        image_size=SIZE,
        progress=False,
        world_options={"heard_reach_m": 0.2},
    )
    np.testing.assert_array_equal(tight.images, wide.images)
    named = tight.heard >= 0
    np.testing.assert_array_equal(tight.heard[named], wide.heard[named])
    assert 0 < named.sum() < (wide.heard >= 0).sum()
    assert tight.meta["world_options"] == {"heard_reach_m": 0.2} and "world_options" not in wide.meta
    with pytest.raises(DatasetError, match="--overwrite"):
        collect_dataset("turtlebot", 300, "test-var-tb-tight", seed=3, image_size=SIZE, progress=False)
    with pytest.raises(DatasetError, match=r"refuses the options .*heard_reach_m must be a distance"):
        collect_dataset("turtlebot", 10, "test-var-tb-bad", world_options={"heard_reach_m": -1.0})


def test_speed_copies_are_faster_and_slower_renderings_of_every_chosen_clip(wordset):
    train = wordset.subset("train")
    speaker = train.speaker[0]
    chosen, others = train.by_speakers([speaker]), train.by_speakers([speaker], keep=False)
    assert set(chosen.speaker) == {speaker} and speaker not in set(others.speaker) and len(others.speaker)
    bank = SoundBank.from_corpus(wordset, ("train",), (speaker,))

    def copies(speed: tuple[float, float], seed: int = 0) -> SoundBank:
        return SoundBank.from_corpus(wordset, ("train",), (speaker,), 2, speed, seed)

    doubled = copies((0.85, 1.15))
    assert len(doubled.features) == 3 * len(bank.features)
    assert np.bincount(doubled.intent).tolist() == (3 * np.bincount(bank.intent)).tolist()
    at_speed_1 = perturbed_features(chosen.clip, wordset.kind, 2, "speed", (1.0, 1.0), seed=0)
    assert np.allclose(at_speed_1, np.repeat(chosen.features, 2, axis=0), atol=1e-3)  # the clips themselves

    def sounding_frames(features: np.ndarray) -> float:
        return float((np.abs(features).sum(axis=2) > 0).sum(axis=1).mean())

    def copies_only(speed: tuple[float, float]) -> np.ndarray:  # the bank sorts its rows by intent
        return perturbed_features(chosen.clip, wordset.kind, 2, "speed", speed, seed=0)

    faster, slower = copies_only((1.25, 1.25)), copies_only((0.8, 0.8))
    assert sounding_frames(faster) < sounding_frames(bank.features)
    assert sounding_frames(slower) > sounding_frames(bank.features)
    assert np.array_equal(copies((0.85, 1.15), seed=3).features, copies((0.85, 1.15), seed=3).features)
    as_notes = dataclasses.replace(wordset, kind="sound")  # a set like notes, where pitch is the command
    with pytest.raises(DatasetError, match="without --speed-copies"):
        SoundBank.from_corpus(as_notes, ("train",), (speaker,), 2, (0.85, 1.15), 0)


def test_voice_copies_are_renderings_of_every_chosen_clip_with_its_formants_moved(wordset):
    """Same length and timing as the clip (the heard frames stay), other features; a warp of 1 is the clip."""
    speaker = wordset.subset("train").speaker[0]
    chosen = wordset.subset("train").by_speakers([speaker])
    bank = SoundBank.from_corpus(wordset, ("train",), (speaker,))
    doubled = SoundBank.from_corpus(wordset, ("train",), (speaker,), voice_copies=2)
    assert len(doubled.features) == 3 * len(bank.features)
    assert np.bincount(doubled.intent).tolist() == (3 * np.bincount(bank.intent)).tolist()

    def copies_only(warp: tuple[float, float]) -> np.ndarray:
        return perturbed_features(chosen.clip, wordset.kind, 2, "voice", warp, seed=0)

    unwarped = copies_only((1.0, 1.0))
    assert np.allclose(unwarped, np.repeat(chosen.features, 2, axis=0), atol=1e-2)
    warped = copies_only((1.15, 1.15))
    heard = np.abs(warped).sum(axis=2) > 0
    assert np.array_equal(heard, np.abs(unwarped).sum(axis=2) > 0)
    assert np.abs(warped - unwarped).mean() > 10 * np.abs(unwarped - np.repeat(chosen.features, 2, 0)).mean()
    as_notes = dataclasses.replace(wordset, kind="sound")
    with pytest.raises(DatasetError, match="without --speed-copies and --voice-copies"):
        SoundBank.from_corpus(as_notes, ("train",), (speaker,), voice_copies=1)


def test_nearest_command_accuracy_is_far_above_chance_for_the_training_clips(pretrained, wordset):
    var = load_var(pretrained.checkpoint)
    train = wordset.subset("train")
    accuracy, hits = nearest_command_accuracy(var, train, train, len(wordset.intent_names))
    assert hits.shape == (len(train.intent),) and accuracy == pytest.approx(hits.mean())
    assert accuracy > 0.6, accuracy  # chance: 0.25
    shuffled = dataclasses.replace(train, intent=np.random.default_rng(0).permutation(train.intent))
    assert nearest_command_accuracy(var, train, shuffled, len(wordset.intent_names))[0] < 0.45
