"""Per-episode offsets of the position the policy is told (`learning.rl.state_offsets`): each episode the
policy's x and y are off by one constant within the spread, a heading is left alone; switched off, nothing
changes and no random number is drawn."""

import numpy as np
import pytest
import torch

from learning.rl.ppo import PPOConfig
from learning.rl.state_offsets import EpisodeStateOffsets

ODOMETRY = torch.tensor([[0.5, -0.2, 0.6, 0.8]])  # x, y, sin, cos (TurtleBot)


def test_switched_off_it_tells_the_real_position_and_draws_nothing() -> None:
    offsets = EpisodeStateOffsets(num_envs=2, state_dim=2, spread_m=0.0)
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    offsets.draw(np.arange(2), rng)
    assert rng.bit_generator.state == before
    states = torch.tensor([[0.1, 0.2], [0.3, 0.4]])
    assert torch.equal(offsets.apply(states, slice(None)), states)


def test_an_episode_is_told_its_x_and_y_off_by_at_most_the_spread_and_its_heading_as_it_is() -> None:
    offsets = EpisodeStateOffsets(num_envs=1, state_dim=4, spread_m=0.05)
    moved = []
    for seed in range(20):
        offsets.draw(np.array([0]), np.random.default_rng(seed))
        told = offsets.apply(ODOMETRY, slice(None))[0]
        shift = told - ODOMETRY[0]
        assert torch.all(shift[:2].abs() <= 0.05) and torch.equal(told[2:], ODOMETRY[0, 2:])
        moved.append(shift[:2].abs().max().item())
    assert max(moved) > 0.025, "the offsets spread over the range"


def test_only_the_environments_whose_episodes_start_get_new_offsets() -> None:
    offsets = EpisodeStateOffsets(num_envs=3, state_dim=2, spread_m=0.05)
    rng = np.random.default_rng(1)
    offsets.draw(np.arange(3), rng)
    kept = offsets.offsets.clone()
    offsets.draw(np.array([1]), rng)
    assert torch.equal(offsets.offsets[[0, 2]], kept[[0, 2]])
    assert not torch.equal(offsets.offsets[1], kept[1])
    told = offsets.apply(torch.zeros(2, 2), np.array([0, 2]))
    assert torch.equal(told, kept[[0, 2]])


@pytest.mark.parametrize("spread", [-0.01, 1.5])
def test_a_run_refuses_an_offset_that_is_negative_or_larger_than_the_workspace(spread: float) -> None:
    with pytest.raises(ValueError, match=rf"policy_state_offset_m must be in \[0, 1\] metres, got {spread}"):
        PPOConfig(policy_state_offset_m=spread).validate()
