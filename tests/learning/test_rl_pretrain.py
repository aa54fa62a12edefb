"""The sparse baseline starts, as in the paper, from encoders pre-trained on one-hot labels: real simulated
views and a real (small) spoken corpus teach them, a policy starts from exactly those weights, and the labels
are counted with the run's."""

from pathlib import Path

import numpy as np
import pytest
import torch
from rl_helpers import tiny_config

from learning.rl.baselines import method_config
from learning.rl.ppo import PPOConfig, PPOTrainer
from learning.rl.pretrain import PretrainConfig, pretrain_encoders, read_encoders
from learning.rl.rewards import corpus_bank
from learning.sounds.build import build_corpora
from learning.var.dataset import NOTHING_HEARD, collect_dataset

pytestmark = [pytest.mark.slow, pytest.mark.speech]

VIEW_SIZE = 32
POLICY_SIZE = 16
VIEWS = 800


@pytest.fixture(scope="module")
def views():
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    return collect_dataset(
        "kuka", VIEWS, "test-pretrain-kuka", seed=4, image_size=VIEW_SIZE, workers=2, progress=False
    )


@pytest.fixture(scope="module")
def encoders(views, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("encoders") / "encoders.pt"
    config = PretrainConfig("test-pretrain-kuka", "wordset", policy_image_size=POLICY_SIZE, steps=300, seed=0)
    return path, pretrain_encoders(config, path, progress=False)


def test_both_encoders_learn_their_one_hot_labels_well_above_chance(views, encoders) -> None:
    _, result = encoders
    image, sound = result["accuracy"]["image"], result["accuracy"]["sound"]
    assert np.mean(views.heard == NOTHING_HEARD) > 0.5  # most views show nothing: chance is per class
    assert image["train_balanced_accuracy"] > 0.2 + 0.3  # four blocks or nothing
    assert sound["train_accuracy"] > 0.25 + 0.3  # four commands
    assert result["labels"]["onehot_image_labels"] == VIEWS
    assert result["labels"]["onehot_sound_labels"] > 0


def sparse_config(path: Path, **overrides: object) -> PPOConfig:
    base = tiny_config(image_size=VIEW_SIZE, policy_image_size=POLICY_SIZE, update_epochs=1, total_steps=24)
    return method_config("sparse", base=base, init_encoders=str(path), **overrides)


def test_a_sparse_run_starts_from_the_pretrained_encoders_and_counts_their_labels(
    encoders, tmp_path: Path
) -> None:
    path, result = encoders
    saved = read_encoders(path)
    trainer = PPOTrainer(sparse_config(path), tmp_path / "run", None, corpus_bank("wordset", "train"))
    try:
        trainer.start()
        assert trainer.policy is not None
        for name, value in saved["image_encoder"].items():
            assert torch.equal(trainer.policy.image_encoder.state_dict()[name], value), name
        for name, value in saved["goal_encoder"].items():
            assert torch.equal(trainer.policy.goal_encoder.state_dict()[name], value), name
        summary = trainer.train(progress=False)
    finally:
        trainer.close()
    onehot = result["labels"]["onehot_image_labels"] + result["labels"]["onehot_sound_labels"]
    assert summary["labels"]["reward_queries"] == 24
    assert summary["labels"]["total"] == onehot + 24


def test_encoders_for_another_image_size_are_refused_with_both_sizes(encoders, tmp_path: Path) -> None:
    path, _ = encoders
    trainer = PPOTrainer(
        sparse_config(path, policy_image_size=24), tmp_path / "run", None, corpus_bank("wordset", "train")
    )
    try:
        with pytest.raises(ValueError, match=r"16 px images.*this policy sees 24 px"):
            trainer.start()
    finally:
        trainer.close()


def test_pretrained_encoders_need_the_baselines_own_goal_encoder(encoders) -> None:
    path, _ = encoders
    with pytest.raises(ValueError, match="goal_encoder='learned'"):
        PPOConfig(init_encoders=str(path)).validate()
