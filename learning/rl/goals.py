"""Where the policy's goal comes from, and the goal each environment works toward in its current episode.

- `VarGoal` (the method): the frozen VAR's f_S(S_goal) of the clip, computed once per clip when the run
  starts; the rollout stores the embedding.
- `LearnedGoal` (the baselines): the clip's MFCC features, read by the policy's own goal encoder, which RL
  trains; the rollout stores the clip's index, and the update encodes each distinct clip once.
"""

from typing import Protocol

import numpy as np
import torch

from learning.rl.policy import GoalEncoder, Policy
from learning.rl.rewards import ClipBank


class GoalSource(Protocol):
    input_shape: tuple[int, ...]  # of one row of `inputs`

    def inputs(self, clips: np.ndarray) -> torch.Tensor:
        """What `Policy.encode_goal` reads for these goal clips, one row per clip."""
        ...

    def allocate(self, steps: int, envs: int) -> torch.Tensor:
        """The rollout buffer of what `stored` returns, (steps, envs, ...)."""
        ...

    def stored(self, clips: np.ndarray, inputs: torch.Tensor) -> torch.Tensor: ...

    def features(self, policy: Policy, stored: torch.Tensor) -> torch.Tensor:
        """Goal features of a minibatch's stored goals (T, B, ...), with gradients."""
        ...


class VarGoal:
    def __init__(self, bank: ClipBank) -> None:
        if bank.embeddings is None:
            raise ValueError("embed the goal clips with the VAR first")
        self.embeddings = bank.embeddings
        self.input_shape = tuple(bank.embeddings.shape[1:])

    def inputs(self, clips: np.ndarray) -> torch.Tensor:
        return self.embeddings[torch.from_numpy(clips)]

    def allocate(self, steps: int, envs: int) -> torch.Tensor:
        return torch.zeros(steps, envs, *self.input_shape)

    def stored(self, clips: np.ndarray, inputs: torch.Tensor) -> torch.Tensor:
        return inputs

    def features(self, policy: Policy, stored: torch.Tensor) -> torch.Tensor:
        return policy.encode_goal(stored)


class LearnedGoal:
    def __init__(self, bank: ClipBank) -> None:
        self.table = torch.from_numpy(bank.features)
        self.input_shape = tuple(bank.features.shape[1:])

    def inputs(self, clips: np.ndarray) -> torch.Tensor:
        return self.table[torch.from_numpy(clips)]

    def allocate(self, steps: int, envs: int) -> torch.Tensor:
        return torch.zeros(steps, envs, dtype=torch.int64)

    def stored(self, clips: np.ndarray, inputs: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(clips)

    def features(self, policy: Policy, stored: torch.Tensor) -> torch.Tensor:
        clips, inverse = torch.unique(stored, return_inverse=True)
        return policy.encode_goal(self.table[clips])[inverse]


def goal_source(kind: GoalEncoder, bank: ClipBank) -> GoalSource:
    return VarGoal(bank) if kind == "var" else LearnedGoal(bank)


class EpisodeGoals:
    """Per environment: the goal clip of its current episode, the policy's input for it and the policy's
    features of it (computed when the episode starts, and again after each update changed the encoder)."""

    def __init__(self, source: GoalSource, bank: ClipBank, num_envs: int, feature_size: int) -> None:
        self.source, self.bank = source, bank
        self.clip = np.zeros(num_envs, dtype=np.int64)
        self.input = torch.zeros(num_envs, *source.input_shape)
        self.features = torch.zeros(num_envs, feature_size)

    def draw(self, envs: np.ndarray, intents: np.ndarray, rng: np.random.Generator, policy: Policy) -> None:
        """A fresh goal clip of each given environment's target intent."""
        self.clip[envs] = self.bank.sample(intents, rng)
        self.input[envs] = self.source.inputs(self.clip[envs])
        self.features[envs] = policy.encode_goal(self.input[envs])

    def refresh(self, policy: Policy) -> None:
        self.features = policy.encode_goal(self.input)

    def stored(self, group: slice) -> torch.Tensor:
        return self.source.stored(self.clip[group], self.input[group])
