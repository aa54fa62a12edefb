"""Per-episode colours of the policy's view (`learning.rl.colours`): each episode shows the policy its view
with the RGB channels shuffled and scaled, and optionally its hues turned, one change per episode (switched
off: tests/learning/test_rl_view_changes.py)."""

import colorsys
import itertools

import numpy as np
import pytest
import torch

from learning.rl.colours import EpisodeColours, hue_turn
from learning.rl.ppo import PPOConfig

VIEW_RGB = (200.0, 100.0, 40.0)


def views(num: int) -> torch.Tensor:
    return torch.tensor(VIEW_RGB).repeat(num, 4, 4, 1).to(torch.uint8)


def test_an_episode_sees_each_channel_once_scaled_by_a_gain_within_the_spread() -> None:
    colours = EpisodeColours(num_envs=1, spread=0.3)
    for seed in range(20):
        colours.draw(np.array([0]), np.random.default_rng(seed))
        shown = colours.apply(views(1), slice(None))[0, 0, 0].float()
        mix = colours.mixes[0]
        sources = mix.argmax(dim=1)
        assert sorted(sources.tolist()) == [0, 1, 2]  # a permutation: no channel lost or doubled
        gains = mix.max(dim=1).values
        assert torch.all((gains >= 0.7) & (gains <= 1.3))
        expected = (gains * torch.tensor(VIEW_RGB)[sources]).round().clamp(0, 255)
        torch.testing.assert_close(shown, expected)


def test_only_the_environments_whose_episodes_start_get_new_colours() -> None:
    colours = EpisodeColours(num_envs=3, spread=0.3)
    rng = np.random.default_rng(1)
    colours.draw(np.arange(3), rng)
    kept = colours.mixes.clone()
    colours.draw(np.array([1]), rng)
    assert torch.equal(colours.mixes[[0, 2]], kept[[0, 2]])
    assert not torch.equal(colours.mixes[1], kept[1])
    shown = colours.apply(views(2), np.array([0, 2]))  # views of envs 0 and 2, in their own colours
    assert torch.equal(shown[1], colours.apply(views(1), np.array([2]))[0])


def test_a_run_refuses_a_spread_that_could_black_out_a_channel() -> None:
    with pytest.raises(ValueError, match=r"policy_colour_jitter must be in \[0, 1\), got 1.5"):
        PPOConfig(policy_colour_jitter=1.5).validate()


def test_a_hue_turn_keeps_greys_grey_and_a_third_of_a_turn_moves_each_channel_to_the_next() -> None:
    grey = torch.ones(3)
    for degrees in (-75.0, 10.0, 60.0):
        torch.testing.assert_close(hue_turn(degrees) @ grey, grey)
    red_to_green = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    torch.testing.assert_close(hue_turn(120.0), red_to_green, atol=1e-6, rtol=0)


def test_with_hue_turns_an_episode_sees_hues_between_the_permutations() -> None:
    colours = EpisodeColours(num_envs=1, spread=0.0, hue_degrees=60.0)
    rng = np.random.default_rng(3)
    hues = set()
    for _ in range(40):
        colours.draw(np.array([0]), rng)
        torch.testing.assert_close(colours.mixes[0] @ torch.ones(3), torch.ones(3))  # greys stay grey
        shown = colours.apply(views(1), slice(None))[0, 0, 0].float() / 255
        hues.add(round(colorsys.rgb_to_hsv(*shown.tolist())[0] * 36))  # hue in 10° bins
    permutation_hues = {round(colorsys.rgb_to_hsv(*p)[0] * 36) for p in _permutations(VIEW_RGB)}
    assert len(hues - permutation_hues) >= 10


def _permutations(rgb: tuple[float, float, float]) -> list[tuple[float, ...]]:
    return [tuple(c / 255 for c in p) for p in itertools.permutations(rgb)]


def test_a_run_refuses_a_hue_turn_beyond_half_a_circle() -> None:
    with pytest.raises(ValueError, match=r"policy_hue_turn must be in \[0, 180\] degrees, got 200"):
        PPOConfig(policy_hue_turn=200.0).validate()
