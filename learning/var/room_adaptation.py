"""Seeing a room by its own light: the image encoder's batch-norm statistics moved toward those of the
room's own camera views, with no labels and no weight changed (adaptive batch normalisation, Li et al. 2016).

A base model normalises each convolution's output with means and variances gathered over its training rooms.
In a room outside them the same layers see other means, and everything after them is off. The robot's own
random views of its room measure that room's: the weights stay as trained, only the statistics move, by
`share` of the way (0.5 by default, chosen over both held-out rooms; bench/results/rooms.json,
`room-adapted-0.5`, measures it on other episodes). The statistics the base had are kept with the adapted
VAR, so a robot moved again adapts from them, not from the last room.

A household fine-tune of the adapted model itself (run parameter `finetune_from_unadapted: false`; by default
it trains the version before adapting) sees each view by the statistics of its own room: the household's
views by the adapted ones, the replayed training-room views by the base's (`seeing_by`, `with_statistics`).
The weights then learn under the statistics each room will be seen with: adapted in the household's room, the
base's given back (share 0) in the training room.
"""

import copy
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from core.rooms import MIN_ROOM_VIEWS
from learning.var.model import VAR, ImageEncoder

BATCH = 100
DEFAULT_SHARE = 0.5
CHECKPOINT_KEY = "room_adaptation"  # a VAR checkpoint's record of its adaptation (with `statistics_before`)

Statistics = dict[str, torch.Tensor]  # state-dict keys of the batch norms' running means and variances


@dataclass(frozen=True)
class RoomAdaptation:
    views: int
    share: float
    # how far each layer's mean moved, in the base's standard deviations (mean over channels)
    mean_shift: list[float]
    statistics_before: Statistics  # the base's, kept so that a later adaptation starts from them

    def to_dict(self) -> dict[str, Any]:
        return {"views": self.views, "share": self.share, "mean_shift": self.mean_shift}


def check_room_views(images: np.ndarray) -> None:
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"room views must be uint8 (N, H, W, 3) images, got {images.dtype} {images.shape}")
    if len(images) < MIN_ROOM_VIEWS:
        raise ValueError(
            f"adapting to a room needs at least {MIN_ROOM_VIEWS} of its camera views, got {len(images)}: "
            "capture more views of the room first"
        )


def batch_norm_statistics(encoder: ImageEncoder) -> Statistics:
    return {
        key: value.detach().clone()
        for key, value in encoder.state_dict().items()
        if key.endswith(("running_mean", "running_var"))
    }


@torch.no_grad()
def adapt_to_room(
    encoder: ImageEncoder,
    images: np.ndarray,
    share: float = DEFAULT_SHARE,
    statistics_before: Statistics | None = None,
) -> RoomAdaptation:
    """Move the encoder's batch-norm statistics `share` of the way from `statistics_before` (default: its
    own) to those of `images`, uint8 views of one room taken as the robot moves. In place; eval mode after.
    Share 0 gives back `statistics_before` (the base model's: for a robot back in its training room, where
    they fit best) and needs no views."""
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"share must be from 0 to 1, got {share}")
    before = statistics_before or batch_norm_statistics(encoder)
    if share == 0.0:
        encoder.load_state_dict(before, strict=False)
        return RoomAdaptation(0, share, [0.0] * (len(before) // 2), before)
    check_room_views(images)
    norms = [module for module in encoder.features.modules() if isinstance(module, nn.BatchNorm2d)]
    encoder.eval()
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None  # a plain average over all batches, not a moving one
        norm.train()
    try:
        for start in range(0, len(images), BATCH):
            encoder.hidden(torch.from_numpy(np.ascontiguousarray(images[start : start + BATCH])))
    finally:
        for norm in norms:
            norm.momentum = 0.1
            norm.eval()
    room = batch_norm_statistics(encoder)
    blended = {key: share * room[key] + (1.0 - share) * before[key] for key in before}
    encoder.load_state_dict(blended, strict=False)
    shifts = []
    for key in sorted(k for k in before if k.endswith("running_mean")):
        spread = before[key.replace("running_mean", "running_var")].add(1e-5).sqrt()
        shifts.append(round(float(((blended[key] - before[key]).abs() / spread).mean()), 4))
    return RoomAdaptation(len(images), share, shifts, before)


def base_statistics(payload: dict[str, Any]) -> Statistics | None:
    """The base's statistics kept in an adapted VAR checkpoint's payload (None: the VAR was never adapted)."""
    return (payload.get(CHECKPOINT_KEY) or {}).get("statistics_before")


@contextmanager
def seeing_by(encoder: ImageEncoder, statistics: Statistics) -> Iterator[None]:
    """Within the block the encoder's batch norms (in eval mode) normalise by `statistics`; its own come back
    after. The buffers are rebound, not overwritten, so a graph built inside stays valid for backward."""
    own = {key: encoder.get_buffer(key) for key in statistics}
    try:
        _rebind(encoder, statistics)
        yield
    finally:
        _rebind(encoder, own)


def with_statistics(var: VAR, statistics: Statistics) -> VAR:
    """A copy of `var` whose image encoder normalises by `statistics`."""
    copied = copy.deepcopy(var)
    copied.image_encoder.load_state_dict(statistics, strict=False)
    return copied


def in_view_order(own: torch.Tensor, replay: torch.Tensor, replayed: np.ndarray) -> torch.Tensor:
    """Rows of `own` (the household's views) and `replay` (the replayed ones, where `replayed`) back in the
    order of the views they came from; gradients flow through both."""
    out = own.new_empty(len(replayed), *own.shape[1:])
    out[torch.from_numpy(~replayed)] = own
    out[torch.from_numpy(replayed)] = replay
    return out


def _rebind(encoder: ImageEncoder, statistics: Statistics) -> None:
    for key, value in statistics.items():
        module_name, _, buffer_name = key.rpartition(".")
        setattr(encoder.get_submodule(module_name), buffer_name, value)
