"""Per-episode colour changes of the policy's view (experimental; `PPOConfig.policy_colour_jitter`).

A base policy trained over randomised rooms still fails in the held-out rooms, although its VAR tells the
goals apart there (bench/results/rooms.json, reward_by_slot_real_voices_unseen_room.json). Of the unseen
room's colours, its blue-grey table costs the policy 19 points in the training room, its orange blocks
nothing (bench/results/rooms_knobs.json): the policy's small image encoder learnt the colours it saw. So each
episode the policy sees its view with the RGB channels in a random order, each scaled by its own gain; the
VAR (the reward and the goal match) always sees the real view. A change is drawn when an episode starts and
kept until it ends, so that one episode looks like one room.

Permutations reach only six hues of a colour; the lamplit room's teal blocks on a purple table still cost the
jittered policy about 12 points each. `hue_degrees` also turns each episode's colours about the grey axis by
an angle within ± that many degrees (greys stay grey), so the hues between the permutations are seen too.
"""

import math

import numpy as np
import torch


class EpisodeColours:
    """One 3×3 colour mix per environment (a permutation matrix with gains); the identity until drawn."""

    def __init__(self, num_envs: int, spread: float, hue_degrees: float = 0.0) -> None:
        self.spread = spread  # gains within 1 ± spread (PPOConfig.validate keeps it in [0, 1))
        self.hue_degrees = hue_degrees  # turns within ± this about the grey axis (0: none, and nothing drawn)
        self.mixes = torch.eye(3).repeat(num_envs, 1, 1)

    @property
    def active(self) -> bool:
        return self.spread > 0.0 or self.hue_degrees > 0.0

    def draw(self, envs: np.ndarray, rng: np.random.Generator) -> None:
        """New colours for the episodes starting in `envs` (does nothing, and draws nothing, when off)."""
        if not self.active:
            return
        for env in np.asarray(envs, dtype=np.int64):
            gains = rng.uniform(1.0 - self.spread, 1.0 + self.spread, size=3)
            mix = torch.zeros(3, 3)
            mix[torch.arange(3), torch.from_numpy(rng.permutation(3))] = torch.from_numpy(gains).float()
            if self.hue_degrees > 0.0:
                mix = mix @ hue_turn(rng.uniform(-self.hue_degrees, self.hue_degrees))
            self.mixes[env] = mix

    def apply(self, images: torch.Tensor, envs: np.ndarray | slice) -> torch.Tensor:
        """uint8 (N, H, W, 3) views of environments `envs` → the colours their episodes are shown in."""
        if not self.active:
            return images
        mixed = torch.einsum("nhwc,ndc->nhwd", images.float(), self.mixes[envs])
        return mixed.round_().clamp_(0, 255).to(torch.uint8)


def hue_turn(degrees: float) -> torch.Tensor:
    """The 3×3 rotation of RGB about the grey axis (1, 1, 1) by `degrees` (Rodrigues' formula)."""
    angle = math.radians(degrees)
    axis = torch.full((3,), 1.0 / math.sqrt(3.0))
    cross = torch.tensor([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return (
        math.cos(angle) * torch.eye(3)
        + math.sin(angle) * cross
        + (1.0 - math.cos(angle)) * torch.outer(axis, axis)
    )
