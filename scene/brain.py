"""The active model as the scene uses it: the VAR puts images and clips on the sphere and gives the reward;
the policy drives the simulated robot toward a goal clip. torch is imported here only (lazily, by the
service)."""

import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from learning.audio import AudioError, features_from_bytes
from learning.rl.ppo import load_policy
from learning.var.checkpoint import load_var


@dataclass
class Goal:
    clip_id: int | None  # None: a live voice, kept nowhere
    embedding: np.ndarray  # (d,) f_S(S_goal)


class Brain:
    """VAR + optional policy loaded from checkpoint bytes (the blob store holds them)."""

    def __init__(self, var_bytes: bytes, policy_bytes: bytes | None) -> None:
        with _as_file(var_bytes) as path:
            self.var = load_var(path)
        self.policy = None
        if policy_bytes is not None:
            with _as_file(policy_bytes) as path:
                self.policy, _payload = load_policy(path)
        self.hidden: torch.Tensor | None = None
        self.goal_features: torch.Tensor | None = None
        self.episode_start = torch.ones(1)

    @property
    def image_size(self) -> int:
        return int(self.var.config.image_size)

    @torch.inference_mode()
    def embed_images(self, images: np.ndarray) -> np.ndarray:
        """uint8 (B, H, W, 3) → (B, d) on the unit sphere."""
        if len(images) == 0:
            return np.zeros((0, 3), dtype=np.float32)
        return self.var.encode_image(torch.from_numpy(np.ascontiguousarray(images))).float().numpy()

    @torch.inference_mode()
    def embed_clip_bytes(self, wavs: list[bytes]) -> list[np.ndarray | None]:
        """One embedding per clip; None for a clip whose audio cannot be read."""
        features, keep = [], []
        for index, data in enumerate(wavs):
            try:
                features.append(features_from_bytes(data, front_end=self.var.front_end))
                keep.append(index)
            except AudioError:
                continue
        result: list[np.ndarray | None] = [None] * len(wavs)
        if features:
            embedded = self.var.encode_sound(torch.from_numpy(np.stack(features))).float().numpy()
            for index, vector in zip(keep, embedded, strict=True):
                result[index] = vector
        return result

    def start_episode(self, goal: Goal) -> None:
        if self.policy is None:
            return
        self.hidden = self.policy.initial_state(1)
        self.episode_start = torch.ones(1)
        with torch.inference_mode():
            self.goal_features = self.policy.encode_goal(torch.from_numpy(goal.embedding[None]).float())

    @torch.inference_mode()
    def act(self, image: np.ndarray, image_embedding: np.ndarray, state: np.ndarray) -> np.ndarray:
        """The policy's mean action (deterministic, as in evaluation) for one observation."""
        if self.policy is None or self.goal_features is None or self.hidden is None:
            raise RuntimeError("no policy episode is running: call start_episode first")
        config = self.policy.config
        images = self.policy.view_of(torch.from_numpy(image[None]))
        var_embedding = torch.from_numpy(image_embedding[None]).float()[:, : config.var_dim]
        mean, _, self.hidden = self.policy.step(
            images,
            var_embedding,
            torch.from_numpy(state[None]).float(),
            self.goal_features,
            self.hidden,
            self.episode_start,
        )
        self.episode_start = torch.zeros(1)
        return mean.clamp(-1.0, 1.0)[0].numpy()


@contextmanager
def _as_file(data: bytes) -> Iterator[Path]:
    """The loaders want a path; checkpoints come from the blob store as bytes."""
    with tempfile.TemporaryDirectory(prefix="varbot-scene-") as folder:
        path = Path(folder) / "checkpoint.pt"
        path.write_bytes(data)
        yield path
