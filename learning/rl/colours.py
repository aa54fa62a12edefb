"""Per-episode colour changes of the policy's view (experimental; `PPOConfig.policy_colour_jitter`).

A base policy trained over randomised rooms still fails in the held-out rooms, although its VAR tells the
goals apart there (bench/results/rooms.json, reward_by_slot_real_voices_unseen_room.json). Of the unseen
room's colours, its blue-grey table costs the policy 19 points in the training room, its orange blocks
nothing (bench/results/rooms_knobs.json): the policy's small image encoder learnt the colours it saw. So each
episode the policy sees its view with the RGB channels in a random order, each scaled by its own gain; the
VAR (the reward and the goal match) always sees the real view. A change is drawn when an episode starts and
kept until it ends, so that one episode looks like one room.
"""

import numpy as np
import torch


class EpisodeColours:
    """One 3×3 colour mix per environment (a permutation matrix with gains); the identity until drawn."""

    def __init__(self, num_envs: int, spread: float) -> None:
        self.spread = spread  # gains within 1 ± spread (PPOConfig.validate keeps it in [0, 1))
        self.mixes = torch.eye(3).repeat(num_envs, 1, 1)

    @property
    def active(self) -> bool:
        return self.spread > 0.0

    def draw(self, envs: np.ndarray, rng: np.random.Generator) -> None:
        """New colours for the episodes starting in `envs` (does nothing, and draws nothing, when off)."""
        if not self.active:
            return
        for env in np.asarray(envs, dtype=np.int64):
            gains = rng.uniform(1.0 - self.spread, 1.0 + self.spread, size=3)
            mix = torch.zeros(3, 3)
            mix[torch.arange(3), torch.from_numpy(rng.permutation(3))] = torch.from_numpy(gains).float()
            self.mixes[env] = mix

    def apply(self, images: torch.Tensor, envs: np.ndarray | slice) -> torch.Tensor:
        """uint8 (N, H, W, 3) views of environments `envs` → the colours their episodes are shown in."""
        if not self.active:
            return images
        mixed = torch.einsum("nhwc,ndc->nhwd", images.float(), self.mixes[envs])
        return mixed.round_().clamp_(0, 255).to(torch.uint8)
