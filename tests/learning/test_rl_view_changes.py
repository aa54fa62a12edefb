"""Per-episode shifts of the policy's view (`learning.rl.view_changes`): each episode the whole view moves by
a few pixels, as a camera moved sideways would move it, after its colours change; switched off, neither
change changes anything or draws a random number."""

import numpy as np
import pytest
import torch

from learning.rl.colours import EpisodeColours
from learning.rl.ppo import PPOConfig
from learning.rl.view_changes import EpisodeShifts, EpisodeViewChanges


def marked_views(num: int, size: int = 8) -> torch.Tensor:
    """Grey views with one red pixel at row 3, column 4."""
    views = torch.full((num, size, size, 3), 90, dtype=torch.uint8)
    views[:, 3, 4] = torch.tensor([250, 0, 0], dtype=torch.uint8)
    return views


@pytest.mark.parametrize(
    "switched_off",
    [
        EpisodeColours(num_envs=2, spread=0.0, hue_degrees=0.0),
        EpisodeShifts(num_envs=2, max_pixels=0),
        EpisodeViewChanges(num_envs=2, colour_jitter=0.0, hue_turn=0.0, shift_pixels=0),
    ],
    ids=["colours", "shifts", "both"],
)
def test_switched_off_a_change_shows_the_real_view_and_draws_nothing(
    switched_off: EpisodeColours | EpisodeShifts | EpisodeViewChanges,
) -> None:
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    switched_off.draw(np.arange(2), rng)
    assert rng.bit_generator.state == before
    assert torch.equal(switched_off.apply(marked_views(2), slice(None)), marked_views(2))


def test_an_episode_sees_its_whole_view_moved_by_its_own_offset_within_the_limit() -> None:
    shifts = EpisodeShifts(num_envs=1, max_pixels=2)
    seen = set()
    for seed in range(30):
        shifts.draw(np.array([0]), np.random.default_rng(seed))
        dy, dx = shifts.offsets[0]
        assert abs(dy) <= 2 and abs(dx) <= 2
        shown = shifts.apply(marked_views(1), slice(None))[0]
        assert shown[3 + dy, 4 + dx].tolist() == [250, 0, 0]
        assert int((shown[..., 0] == 250).sum()) == 1  # moved, not smeared: the edges repeat plain grey
        seen.add((int(dy), int(dx)))
    assert len(seen) >= 10


def test_only_the_environments_whose_episodes_start_get_new_offsets() -> None:
    shifts = EpisodeShifts(num_envs=3, max_pixels=3)
    rng = np.random.default_rng(5)
    shifts.draw(np.arange(3), rng)
    kept = shifts.offsets.copy()
    for _ in range(5):
        shifts.draw(np.array([1]), rng)
    assert np.array_equal(shifts.offsets[[0, 2]], kept[[0, 2]])
    shown = shifts.apply(marked_views(2), np.array([0, 2]))
    assert torch.equal(shown[1], shifts.apply(marked_views(1), np.array([2]))[0])


def test_a_view_gets_its_episodes_colours_and_then_its_shift() -> None:
    changes = EpisodeViewChanges(num_envs=1, colour_jitter=0.2, hue_turn=0.0, shift_pixels=2)
    changes.draw(np.array([0]), np.random.default_rng(7))
    expected = changes.shifts.apply(changes.colours.apply(marked_views(1), slice(None)), slice(None))
    assert torch.equal(changes.apply(marked_views(1), slice(None)), expected)


def test_a_run_refuses_a_shift_that_could_push_half_the_view_out() -> None:
    with pytest.raises(ValueError, match=r"policy_view_shift must be in \[0, 16\) pixels of the policy's 32"):
        PPOConfig(policy_image_size=32, policy_view_shift=16).validate()
