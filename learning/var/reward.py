"""The intrinsic reward of the method: how well what the robot sees matches the goal command."""

import numpy as np
import torch

from learning.var.model import VAR


def _as_rows(embedding: torch.Tensor, batch: int, name: str) -> torch.Tensor:
    embedding = torch.as_tensor(embedding, dtype=torch.float32)
    if embedding.ndim == 1:
        embedding = embedding.expand(batch, -1)
    if embedding.ndim != 2 or embedding.shape[0] != batch:
        raise ValueError(f"{name} must be (d,) or (B, d) with B = {batch}, got {tuple(embedding.shape)}.")
    return embedding


@torch.inference_mode()
def intrinsic_reward(
    var: VAR,
    images: torch.Tensor | np.ndarray,
    goal_embedding: torch.Tensor,
    current_sound_embedding: torch.Tensor | None = None,
) -> torch.Tensor:
    """r = f_I(I) · f_S(S_goal) [+ f_S(S_t) · f_S(S_goal)] for a batch of uint8 images (B, H, W, 3).

    `goal_embedding` is (d,) or (B, d). `current_sound_embedding` (d,) or (B, d) adds the current-sound term;
    a zero row means nothing was heard at that step and adds nothing. The VAR must be frozen (eval mode).
    """
    if var.training:
        raise ValueError(
            "intrinsic_reward needs a frozen VAR: call var.eval() (load_var returns one in eval mode)."
        )
    images = torch.as_tensor(images)
    reward = (var.encode_image(images) * _as_rows(goal_embedding, len(images), "goal_embedding")).sum(dim=1)
    if current_sound_embedding is not None:
        current = _as_rows(current_sound_embedding, len(images), "current_sound_embedding")
        reward = reward + (current * _as_rows(goal_embedding, len(images), "goal_embedding")).sum(dim=1)
    return reward
