"""Per-episode changes of the policy's view (experimental): its colours (`learning.rl.colours`) and a shift.

The lamplit room's camera (6 cm / 5° off, outside the training ranges by design) alone costs the colour-
jittered Kuka policy 24 points in the training room (bench/results/rooms_knobs.json). A shift of the whole
view by a few pixels, drawn when an episode starts and kept until it ends, is what a camera moved sideways
looks like to the policy: the gripper and the blocks move together, so only where they are relative to each
other stays telling. The VAR always sees the real view.
"""

import numpy as np
import torch

from learning.rl.colours import EpisodeColours


class EpisodeShifts:
    """One (dy, dx) pixel shift per environment, within ± `max_pixels`; the edges repeat into the gap."""

    def __init__(self, num_envs: int, max_pixels: int) -> None:
        self.max_pixels = max_pixels
        self.offsets = np.zeros((num_envs, 2), dtype=np.int64)

    @property
    def active(self) -> bool:
        return self.max_pixels > 0

    def draw(self, envs: np.ndarray, rng: np.random.Generator) -> None:
        """New shifts for the episodes starting in `envs` (draws nothing when off)."""
        if not self.active:
            return
        for env in np.asarray(envs, dtype=np.int64):
            self.offsets[env] = rng.integers(-self.max_pixels, self.max_pixels + 1, size=2)

    def apply(self, images: torch.Tensor, envs: np.ndarray | slice) -> torch.Tensor:
        """(N, H, W, C) views of environments `envs` → the same views shifted by their episodes' offsets."""
        if not self.active:
            return images
        offsets = torch.from_numpy(self.offsets[envs])
        count, height, width = images.shape[:3]
        rows = (torch.arange(height) - offsets[:, :1]).clamp_(0, height - 1)  # (N, H): the source row of each
        cols = (torch.arange(width) - offsets[:, 1:]).clamp_(0, width - 1)
        return images[torch.arange(count)[:, None, None], rows[:, :, None], cols[:, None, :]]


class EpisodeViewChanges:
    """The colours, then the shift, of each environment's episode."""

    def __init__(self, num_envs: int, colour_jitter: float, hue_turn: float, shift_pixels: int) -> None:
        self.colours = EpisodeColours(num_envs, colour_jitter, hue_turn)
        self.shifts = EpisodeShifts(num_envs, shift_pixels)

    def draw(self, envs: np.ndarray, rng: np.random.Generator) -> None:
        self.colours.draw(envs, rng)
        self.shifts.draw(envs, rng)

    def apply(self, images: torch.Tensor, envs: np.ndarray | slice) -> torch.Tensor:
        return self.shifts.apply(self.colours.apply(images, envs), envs)
