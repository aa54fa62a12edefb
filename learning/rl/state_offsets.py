"""Per-episode offsets of the position the policy is told (experimental; `PPOConfig.policy_state_offset_m`).

A base policy loses 15 points in the training room when the camera is moved by 2 cm and 2° (bench/results/
rooms_knobs.json, "training-room-plus-one-unseen-knob"), and its failed episodes end a few centimetres beside
the commanded block, not at another one. That is what a policy does when it reads the block's position off
fixed pixels and steers its told position (M_t: the gripper's x, y, or the base's odometry) to it, instead of
bringing the gripper and the block together in the image. So each episode the position the policy is told is
off by a constant offset in x and y; the world, the reward and the VAR are unchanged. An offset is drawn when
an episode starts and kept until it ends.
"""

import numpy as np
import torch

POSITION_DIMS = 2  # M_t starts with the (x, y) position in every world; the rest (a heading) is left alone


class EpisodeStateOffsets:
    """One (x, y) offset per environment, in metres; zero until drawn."""

    def __init__(self, num_envs: int, state_dim: int, spread_m: float) -> None:
        self.spread_m = spread_m  # offsets within ± spread_m in each of x and y (PPOConfig.validate: ≥ 0)
        self.offsets = torch.zeros(num_envs, state_dim)

    @property
    def active(self) -> bool:
        return self.spread_m > 0.0

    def draw(self, envs: np.ndarray, rng: np.random.Generator) -> None:
        """New offsets for the episodes starting in `envs` (does nothing, and draws nothing, when off)."""
        if not self.active:
            return
        for env in np.asarray(envs, dtype=np.int64):
            offset = rng.uniform(-self.spread_m, self.spread_m, size=POSITION_DIMS)
            self.offsets[env, :POSITION_DIMS] = torch.from_numpy(offset).float()

    def apply(self, states: torch.Tensor, envs: np.ndarray | slice) -> torch.Tensor:
        """(N, state_dim) states of environments `envs` → the positions their episodes are told."""
        if not self.active:
            return states
        return states + self.offsets[envs]
