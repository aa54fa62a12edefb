"""The rewards of the RL stage, checked against values worked out by hand."""

import math

import numpy as np
import pytest
import torch

from learning.rl.rewards import (
    ClipBank,
    CurrentSound,
    intrinsic_reward_from_embeddings,
    shaped_reward,
    sparse_reward,
)
from learning.var.model import VAR, VARConfig
from learning.var.reward import intrinsic_reward


def unit(*values: float) -> list[float]:
    norm = math.sqrt(sum(v * v for v in values))
    return [v / norm for v in values]


def test_intrinsic_reward_is_the_dot_product_of_image_and_goal_embeddings() -> None:
    image = torch.tensor([[1.0, 0.0, 0.0], unit(1, 1, 0), [0.0, 0.0, -1.0]])
    goal = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    reward = intrinsic_reward_from_embeddings(image, goal)
    assert reward.tolist() == pytest.approx([1.0, math.sqrt(0.5), -1.0])


def test_current_sound_adds_its_dot_product_with_the_goal() -> None:
    image = torch.tensor([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    goal = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    current = torch.tensor([[0.0, 0.0, 1.0], [0.8, 0.6, 0.0]])
    reward = intrinsic_reward_from_embeddings(image, goal, current)
    assert reward.tolist() == pytest.approx([1.0 + 0.0, 0.6 + 0.8])


def test_trainer_reward_matches_the_var_reward_helper_on_a_real_var() -> None:
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=32)).eval()
    images = torch.randint(0, 256, (5, 32, 32, 3), dtype=torch.uint8)
    with torch.inference_mode():
        goal = var.encode_sound(torch.randn(5, 100, 40))
        embedded = var.encode_image(images)
    ours = intrinsic_reward_from_embeddings(embedded, goal)
    theirs = intrinsic_reward(var, images, goal)
    assert torch.allclose(ours, theirs, atol=1e-6)
    assert ours.abs().max() <= 1.0 + 1e-6  # unit vectors: the reward is a cosine


def test_sparse_reward_is_one_only_when_an_episode_ends_in_success() -> None:
    done = np.array([True, True, False, False])
    success = np.array([True, False, True, False])
    assert sparse_reward(done, success).tolist() == [1.0, 0.0, 0.0, 0.0]


def test_shaped_reward_counts_progress_in_action_steps_plus_success() -> None:
    before = np.array([0.10, 0.10, 0.05])
    after = np.array([0.08, 0.13, 0.05])
    done = np.array([False, False, True])
    success = np.array([False, False, True])
    # 2 cm closer = one full step; 3 cm further = -1.5 steps; at the end on target = +1
    assert shaped_reward(before, after, done, success).tolist() == pytest.approx([1.0, -1.5, 1.0])


def test_goals_are_drawn_from_the_clips_of_the_requested_intent() -> None:
    bank = ClipBank(np.zeros((6, 100, 40), np.float32), np.array([0, 0, 1, 1, 2, 3]))
    rng = np.random.default_rng(0)
    picks = bank.sample(np.array([0, 1, 2, 3] * 25), rng)
    assert (bank.intents[picks] == np.array([0, 1, 2, 3] * 25)).all()
    assert set(picks[::4].tolist()) == {0, 1}  # both clips of intent 0 get used


def test_a_goal_list_missing_an_intent_is_refused_with_a_clear_message() -> None:
    bank = ClipBank(np.zeros((2, 100, 40), np.float32), np.array([0, 1]))
    with pytest.raises(ValueError, match="no goal clip for intent 3"):
        bank.sample(np.array([3]), np.random.default_rng(0))


def test_current_sound_is_silence_when_nothing_is_heard() -> None:
    bank = ClipBank(np.zeros((2, 100, 40), np.float32), np.array([0, 1]))
    bank.embeddings = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    silence = torch.tensor([0.0, 0.0, 1.0])
    current = CurrentSound(bank, silence).embeddings(np.array([-1, 1, 0]), np.random.default_rng(0))
    assert current.tolist() == [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
