"""Stage 1: fine-tune the VAR on the household's own triplets (their voices, their room).

Explicit triplets from pair labels (see `worker.household`), the paper's triplet loss, Adam, the VAR trainer's
augmentations (sound: `learning.augment.augment_features`, or `augment_embeddings` for a speech-embedding VAR;
image: shift + brightness/contrast). A checkpoint with the optimiser and RNG state is written after every
epoch, so a killed worker resumes where it stopped; the weights with the best held-out triplet accuracy are
kept.
"""

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from learning.var.checkpoint import load_var, read_checkpoint, save_var
from learning.var.model import VAR
from learning.var.room_adaptation import CHECKPOINT_KEY as ROOM_ADAPTATION
from learning.var.room_adaptation import (
    Statistics,
    base_statistics,
    in_view_order,
    seeing_by,
    with_statistics,
)
from worker.household import REPLAYED_VIEW, SILENCE_ROW, HouseholdData


class Diverged(RuntimeError):
    """The loss became NaN or infinite."""


@dataclass
class VarFinetuneResult:
    checkpoint: Path
    epochs: int
    steps: int
    train_triplets: int
    held_out_triplets: int
    best_held_out_accuracy: float | None
    seconds: float


def sound_batch(data: HouseholdData, rows: np.ndarray) -> torch.Tensor:
    """MFCC features for clip rows, silence (all zeros) for SILENCE_ROW."""
    out = np.zeros((len(rows), *data.features.shape[1:]), dtype=np.float32)
    spoken = rows != SILENCE_ROW
    out[spoken] = data.features[rows[spoken]]
    return torch.from_numpy(out)


@torch.inference_mode()
def triplet_accuracy(var: VAR, data: HouseholdData, triplets: np.ndarray) -> float | None:
    """Share of triplets with ‖v_i − v+‖ < ‖v_i − v−‖ (None when there are none)."""
    if len(triplets) == 0:
        return None
    var.eval()
    anchor = var.encode_image(torch.from_numpy(data.images[triplets[:, 0]]))
    positive = var.encode_sound(sound_batch(data, triplets[:, 1]))
    negative = var.encode_sound(sound_batch(data, triplets[:, 2]))
    closer = (anchor - positive).pow(2).sum(1) < (anchor - negative).pow(2).sum(1)
    return float(closer.float().mean())


def keep_room_statistics(var: VAR) -> None:
    """A VAR adapted to the household's room (`worker.room_adaptation`) trains with its image encoder's batch
    norms in eval mode: it learns under the room's statistics and leaves them as they are, where batch
    statistics would pull them toward a mix of the room and the replayed training room."""
    for module in var.image_encoder.modules():
        if isinstance(module, torch.nn.BatchNorm2d):
            module.eval()


def encode_views(
    var: VAR, images: torch.Tensor, replayed: np.ndarray, replay_statistics: Statistics | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """f_I of a batch of views and the hidden layer it came from (what a policy that sees through the VAR
    reads). With `replay_statistics` (the base's, for a VAR adapted to the household's room) the `replayed`
    ones, views of the training room, are seen by them, the household's by the room's."""
    if replay_statistics is None or not replayed.any():
        return var.encode_image_and_hidden(images)
    with seeing_by(var.image_encoder, replay_statistics):
        replay = var.encode_image_and_hidden(images[torch.from_numpy(replayed)])
    own = var.encode_image_and_hidden(images[torch.from_numpy(~replayed)])
    return in_view_order(own[0], replay[0], replayed), in_view_order(own[1], replay[1], replayed)


class ViewAnchor:
    """Keeps the hidden layer of the replayed training-room views where the VAR the fine-tune started from had
    it. The triplet loss constrains only the sphere, and a policy that sees through the VAR reads the hidden
    layer: left free, it moved far enough in one household's fine-tune that the base policy, seeing through
    it, fell from 86 to 67 % in the training room before PPO began (README, *Choosing the policy*). The
    distance is the mean squared difference over the start's variance of a unit across the batch (as
    `learning.var.room_invariance` measures its student against the target's spread)."""

    def __init__(self, start: VAR, weight: float) -> None:
        self.start = start.eval()
        self.weight = weight

    def drift(self, images: torch.Tensor, hidden: torch.Tensor, replayed: np.ndarray) -> torch.Tensor:
        """How far the replayed views' hidden layer moved from the start's, in units of its spread there."""
        rows = torch.from_numpy(replayed)
        with torch.no_grad():
            target = self.start.image_encoder.hidden(images[rows])
        spread = target.var(dim=0, unbiased=False).mean().clamp_min(1e-6)
        return (hidden[rows] - target).pow(2).mean() / spread


def finetune_var(
    data: HouseholdData,
    init_checkpoint: Path,
    work_dir: Path,
    epochs: int,
    batch_size: int,
    learning_rate: float,
    seed: int,
    on_epoch: Callable[[float, dict[str, Any]], bool],
    margin: float = 1.0,
    keep_view: float = 0.0,
) -> VarFinetuneResult:
    """`on_epoch(fraction, record)` after every epoch; returning True stops (cancel) after the checkpoint.
    `keep_view` > 0 adds `keep_view` × `ViewAnchor.drift` of the replayed views to the loss."""
    from learning.augment import augment_embeddings, augment_features
    from learning.var.image_augment import augment_images
    from learning.var.loss import triplet_loss

    work_dir.mkdir(parents=True, exist_ok=True)
    last, best = work_dir / "last.pt", work_dir / "best.pt"
    init_payload = read_checkpoint(init_checkpoint)
    var = load_var(init_checkpoint)
    replay_statistics = base_statistics(init_payload)
    view_anchor = None
    if keep_view > 0:  # the start as it sees the training room: an adapted one by the base's statistics
        start = load_var(init_checkpoint)
        view_anchor = ViewAnchor(
            start if replay_statistics is None else with_statistics(start, replay_statistics), keep_view
        )
    optimizer = torch.optim.Adam(var.parameters(), lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)
    state = {"epoch": 0, "step": 0, "best": None, "seconds": 0.0}
    if last.is_file():
        payload = read_checkpoint(last)
        var.load_state_dict(payload["state_dict"])
        optimizer.load_state_dict(payload["training"]["optimizer"])
        generator.set_state(payload["training"]["generator"])
        state = {k: payload["training"][k] for k in state}
    train, test = data.train_triplets, data.test_triplets
    if state["best"] is None and not best.is_file():
        state["best"] = triplet_accuracy(var, data, test)
        _save(var, best, init_payload, state, optimizer, generator)
    started = time.perf_counter()
    while state["epoch"] < epochs:
        var.train()
        if replay_statistics is not None:  # an adapted VAR
            keep_room_statistics(var)
        order = np.random.default_rng([seed, 21, state["epoch"]]).permutation(len(train))
        losses, drifts = [], []
        for start in range(0, len(train), batch_size):
            rows = train[order[start : start + batch_size]]
            if len(rows) < 2:  # batch norm cannot train on a single image
                continue
            images = augment_images(torch.from_numpy(data.images[rows[:, 0]]), generator)
            augment_sounds = augment_features if var.front_end == "mfcc" else augment_embeddings
            sounds = augment_sounds(
                torch.cat([sound_batch(data, rows[:, 1]), sound_batch(data, rows[:, 2])]), generator
            )
            positive, negative = var.encode_sound(sounds).split(len(rows))
            replayed = data.snapshot_ids[rows[:, 0]] == REPLAYED_VIEW
            anchor, hidden = encode_views(var, images, replayed, replay_statistics)
            loss = triplet_loss(anchor, positive, negative, margin)
            if view_anchor is not None and replayed.any():
                drift = view_anchor.drift(images, hidden, replayed)
                loss = loss + view_anchor.weight * drift
                drifts.append(float(drift.detach()))
            if not torch.isfinite(loss):
                raise Diverged(f"the triplet loss became {loss.item()} at step {state['step'] + 1}")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
            state["step"] += 1
        state["epoch"] += 1
        held_out = triplet_accuracy(var, data, test)
        if held_out is not None and (state["best"] is None or held_out >= state["best"]):
            state["best"] = held_out
            _save(var, best, init_payload, state, optimizer, generator)
        state["seconds"] += time.perf_counter() - started
        started = time.perf_counter()
        _save(var, last, init_payload, state, optimizer, generator)
        record = {
            "epoch": state["epoch"],
            "step": state["step"],
            "loss": float(np.mean(losses)),
            "held_out_accuracy": held_out,
            # with the view anchor on: how far the replayed views' hidden layer moved (ViewAnchor.drift)
            "view_drift": float(np.mean(drifts)) if drifts else None,
        }
        if on_epoch(state["epoch"] / epochs, record):
            from worker.progress import Cancelled

            raise Cancelled("cancel requested during the VAR fine-tune")
    chosen = best if len(test) and best.is_file() else last
    final = work_dir / "final.pt"
    payload = read_checkpoint(chosen)
    payload.pop("training", None)
    torch.save(payload, final)
    return VarFinetuneResult(
        checkpoint=final,
        epochs=state["epoch"],
        steps=state["step"],
        train_triplets=len(train),
        held_out_triplets=len(test),
        best_held_out_accuracy=state["best"],
        seconds=state["seconds"],
    )


def _save(
    var: VAR,
    path: Path,
    init_payload: dict[str, Any],
    state: dict[str, Any],
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
) -> None:
    kept = ("manifest_hash", "sound_set", "world", ROOM_ADAPTATION)
    keep = {k: init_payload[k] for k in kept if k in init_payload}
    save_var(
        var,
        path,
        **keep,
        finetuned_on="household triplets",
        training={**state, "optimizer": optimizer.state_dict(), "generator": generator.get_state()},
    )
