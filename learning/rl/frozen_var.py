"""The frozen VAR of a run, read from its checkpoint once: the model, its path, the labels behind it."""

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from learning.var.model import VAR
from learning.var.room_adaptation import Statistics, base_statistics


@dataclass(frozen=True)
class LoadedVar:
    model: VAR  # eval mode, no gradients
    path: str | None = None  # None: a VAR made in memory (tests, benchmarks)
    label_counts: dict[str, int] = field(default_factory=dict)  # {"var_triplet_labels": n} when known
    # a VAR adapted to a room (learning.var.room_adaptation) keeps the base's batch-norm statistics
    base_statistics: Statistics | None = None

    @classmethod
    def in_memory(cls, model: VAR) -> "LoadedVar":
        return cls(model.eval().requires_grad_(False))

    @property
    def image_size(self) -> int:
        return int(self.model.config.image_size)

    @property
    def embedding_dim(self) -> int:
        return int(self.model.config.embedding_dim)


def load_frozen_var(path: str | Path | None) -> LoadedVar | None:
    """The VAR at `path` (None: no VAR), frozen, with the labels it was trained on counted."""
    if path is None:
        return None
    from learning.var.checkpoint import load_state_into, read_checkpoint
    from learning.var.model import VARConfig

    payload = read_checkpoint(path)
    model = VAR(VARConfig.from_dict(payload["config"]))
    load_state_into(model, payload, path)
    return LoadedVar(
        model.eval().requires_grad_(False), str(path), triplet_labels(payload), base_statistics(payload)
    )


def triplet_labels(payload: dict[str, Any]) -> dict[str, int]:
    """Labels behind a VAR, counted as the paper does: 2 per triplet of the dataset it was trained on."""
    from core.paths import data_dir

    dataset = (payload.get("train_config") or {}).get("dataset")
    if not dataset:
        return {}
    for folder in (Path(dataset), data_dir() / "var" / "datasets" / dataset):
        meta = folder / "meta.json"
        if meta.is_file():
            return {"var_triplet_labels": 2 * int(json.loads(meta.read_text())["count"])}
    return {}


class VarOnDevice:
    """A frozen VAR whose weights sit on `device` (a GPU): it takes and returns CPU tensors as the VAR does,
    so the trainer's buffers and rewards stay on the CPU."""

    def __init__(self, model: VAR, device: torch.device) -> None:
        self.model = model.to(device)
        self.device = device
        self.config = model.config

    def encode_image(self, images: torch.Tensor) -> torch.Tensor:
        return self.model.encode_image(images.to(self.device)).cpu()

    def encode_image_and_hidden(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        embedding, hidden = self.model.encode_image_and_hidden(images.to(self.device))
        return embedding.cpu(), hidden.cpu()

    def encode_sound(self, features: torch.Tensor) -> torch.Tensor:
        return self.model.encode_sound(features.to(self.device)).cpu()

    def encode_silence(self) -> torch.Tensor:
        with self.device:  # the VAR makes its silence with torch.zeros: on the weights' device
            return self.model.encode_silence().cpu()
