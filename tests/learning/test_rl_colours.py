"""Per-episode colours of the policy's view (`learning.rl.colours`): each episode shows the policy its view
with the RGB channels shuffled and scaled, one change per episode; switched off, nothing changes and no
random number is drawn."""

import numpy as np
import pytest
import torch

from learning.rl.colours import EpisodeColours
from learning.rl.ppo import PPOConfig

VIEW_RGB = (200.0, 100.0, 40.0)


def views(num: int) -> torch.Tensor:
    return torch.tensor(VIEW_RGB).repeat(num, 4, 4, 1).to(torch.uint8)


def test_switched_off_it_shows_the_real_view_and_draws_nothing() -> None:
    colours = EpisodeColours(num_envs=2, spread=0.0)
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    colours.draw(np.arange(2), rng)
    assert rng.bit_generator.state == before
    assert torch.equal(colours.apply(views(2), slice(None)), views(2))


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
