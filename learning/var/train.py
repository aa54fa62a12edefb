"""The one VAR training entry point, for pre-training on simulated triplets and for fine-tuning on new ones.

`train(TrainConfig(...))` draws triplets (image, positive clip, negative clip) batch by batch from a triplet
dataset and a sound corpus, optimises the triplet loss with Adam and a warm-up + cosine schedule, logs metrics
as JSON lines, plots them, checkpoints (and resumes from) `run_dir/last.pt`, and stops early on a held-out
part of the images when asked. Fine-tuning is the same call with `init_checkpoint` and, optionally, a replay
sample of the original triplets.
"""

import dataclasses
import json
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from core.plain import as_lists
from learning.front_ends import MFCC
from learning.var.checkpoint import (
    CheckpointMismatchError,
    check_manifest,
    load_state_into,
    read_checkpoint,
    save_var,
)
from learning.var.dataset import DatasetError, ImageDataset, SoundBank, draw_triplet_sounds, open_dataset
from learning.var.image_augment import augment_images
from learning.var.loss import triplet_correct, triplet_loss, triplet_losses
from learning.var.model import VAR, VARConfig


@dataclass
class TrainConfig:
    """Hyperparameters and inputs of one training run (pre-training or fine-tuning)."""

    dataset: str  # triplet dataset name (under data_dir()/var/datasets) or path
    sounds: str  # sound corpus name, e.g. "wordset"
    run_dir: str  # checkpoints, metrics.jsonl, metrics.png
    sound_splits: tuple[str, ...] = ("train",)
    sound_speakers: tuple[str, ...] | None = None  # restrict the clips to these speakers (a new voice)
    sound_speed_copies: int = 0  # add this many speed-perturbed renderings of every clip to the bank
    sound_speed_range: tuple[float, float] = (0.85, 1.15)  # playback-rate factors of those copies
    sound_room_copies: int = 0  # add this many recordings of every clip in simulated rooms to the bank
    sound_voice_copies: int = 0  # add this many renderings of every clip with its formants moved
    sound_voice_range: tuple[float, float] = (0.85, 1.15)  # formant warp factors of those copies
    model: VARConfig = field(default_factory=VARConfig)  # image_size is taken from the dataset
    epochs: int = 12
    max_steps: int | None = None  # overrides epochs: the schedule length in optimiser steps
    batch_size: int = 128
    lr: float = 2e-3
    weight_decay: float = 1e-5
    warmup_steps: int = 100
    final_lr_fraction: float = 0.02
    margin: float = 1.0
    val_fraction: float = 0.05
    eval_every_steps: int | None = None  # None: once per epoch
    patience: int | None = None  # stop after this many evaluations without a better held-out accuracy
    augment: bool = True  # sounds: learning.augment (per front end); images: shift + brightness/contrast
    image_shift_fraction: float = 0.04
    image_jitter: float = 0.1
    in_view_share: float | None = 0.5  # share of each batch with a target in view; None: sample uniformly
    init_checkpoint: str | None = None  # fine-tuning: start from these weights
    replay_dataset: str | None = None  # fine-tuning: original triplets mixed into every batch
    replay_sounds: str | None = None  # corpus for the replay triplets (default: `sounds`)
    replay_fraction: float = 0.0
    seed: int = 0
    threads: int = 2
    log_every_steps: int = 20
    checkpoint_every_steps: int = 200
    progress: bool = True

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "TrainConfig":
        data = dict(data)
        data["model"] = VARConfig.from_dict(data.get("model", {}))
        for key in ("sound_splits", "sound_speakers", "sound_speed_range", "sound_voice_range"):
            if data.get(key) is not None:
                data[key] = tuple(data[key])
        return cls(**{k: v for k, v in data.items() if k in cls.__dataclass_fields__})


@dataclass
class TrainResult:
    run_dir: Path
    checkpoint: Path  # best held-out weights when early stopping, else the last
    steps: int
    epochs_completed: float
    seconds: float
    triplets_per_second: float
    best_val_accuracy: float | None  # balanced: mean of the accuracies with and without a target in view
    final_val_accuracy: float | None
    stopped_early: bool
    interrupted: bool


@dataclass
class TripletSource:
    """Images of one dataset (split into training and held-out rows) plus the clips to pair them with."""

    images: ImageDataset
    sounds: SoundBank
    train_rows: np.ndarray
    val_rows: np.ndarray

    def batch(self, rows: np.ndarray, rng: np.random.Generator):
        positive, negative = draw_triplet_sounds(self.images.heard[rows], self.sounds, rng)
        return self.images.read_images(rows), positive, negative


def _split_rows(count: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rows = np.random.default_rng([seed, 7]).permutation(count)
    held_out = round(count * val_fraction) if val_fraction > 0 else 0
    if held_out and count - held_out < 1:
        raise DatasetError(f"Only {count} images: too few to hold {val_fraction:.0%} out.")
    return np.sort(rows[held_out:]), np.sort(rows[:held_out])


def _load_corpus(name: str, front_end: str, progress: bool):
    """The corpus with the features the model's sound front end reads (computed once, then cached)."""
    from learning.sounds import load_corpus

    return load_corpus(name, front_end=front_end, progress=progress)


def _sound_augmenter(
    enabled: bool, front_end: str
) -> Callable[[torch.Tensor, torch.Generator], torch.Tensor] | None:
    if not enabled:
        return None
    from learning.augment import augment_embeddings, augment_features

    return augment_features if front_end == MFCC else augment_embeddings


def _schedule(config: TrainConfig, total_steps: int) -> Callable[[int], float]:
    def factor(step: int) -> float:
        if step < config.warmup_steps:
            return (step + 1) / config.warmup_steps
        progress = min(1.0, (step - config.warmup_steps) / max(1, total_steps - config.warmup_steps))
        cosine = 0.5 * (1 + math.cos(math.pi * progress))
        return config.final_lr_fraction + (1 - config.final_lr_fraction) * cosine

    return factor


class _Trainer:
    def __init__(self, config: TrainConfig, callback: Callable[[dict], bool] | None) -> None:
        self.config, self.callback = config, callback
        self.run_dir = Path(config.run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(config.threads)  # after any forks: collection workers are spawned, not forked
        random.seed(config.seed)
        torch.manual_seed(config.seed)  # before the model is built: its initial weights come from here

        images = open_dataset(config.dataset)
        corpus = _load_corpus(config.sounds, config.model.front_end, config.progress)
        self.corpus_hash = corpus.manifest_hash
        train_rows, val_rows = _split_rows(len(images), config.val_fraction, config.seed)
        bank = SoundBank.from_corpus(
            corpus, config.sound_splits, config.sound_speakers, config.sound_speed_copies,
            config.sound_speed_range, config.seed, config.sound_room_copies, config.sound_voice_copies,
            config.sound_voice_range,
        )  # fmt: skip
        self.source = TripletSource(images, bank, train_rows, val_rows)
        self.replay = self._replay_source()
        self.model_config = dataclasses.replace(config.model, image_size=images.image_size)
        self.model = VAR(self.model_config)
        self.model.set_sound_statistics(torch.from_numpy(bank.features))
        self.model = self.model.to(memory_format=torch.channels_last)
        self.new_per_batch = config.batch_size - (
            round(config.batch_size * config.replay_fraction) if self.replay else 0
        )
        self.steps_per_epoch = max(1, len(train_rows) // self.new_per_batch)
        self.total_steps = config.max_steps or config.epochs * self.steps_per_epoch
        self.optimizer = torch.optim.Adam(
            self.model.parameters(), lr=config.lr, weight_decay=config.weight_decay
        )
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, _schedule(config, self.total_steps)
        )
        self.augment = _sound_augmenter(config.augment, config.model.front_end)
        self.rng = np.random.default_rng([config.seed, 1])
        self.torch_rng = torch.Generator().manual_seed(config.seed)
        self.step, self.best_val, self.last_val, self.evals_since_best = 0, None, None, 0
        self.trained_seconds = 0.0
        self.val_batches = self._fixed_val_batches(self.source, seed=config.seed)
        self.replay_val_batches = (
            self._fixed_val_batches(self.replay, seed=config.seed) if self.replay else None
        )
        if config.init_checkpoint:
            self._start_from(config.init_checkpoint)

    # -- inputs

    def _replay_source(self) -> TripletSource | None:
        config = self.config
        if not config.replay_dataset or config.replay_fraction <= 0:
            return None
        images = open_dataset(config.replay_dataset)
        corpus = _load_corpus(config.replay_sounds or config.sounds, config.model.front_end, config.progress)
        if config.init_checkpoint:  # replayed sounds must be the ones the checkpoint learnt from
            payload = read_checkpoint(config.init_checkpoint)
            if payload.get("sound_set") == (config.replay_sounds or config.sounds):
                check_manifest(payload, corpus.manifest_hash, config.init_checkpoint)
        train_rows, val_rows = _split_rows(len(images), config.val_fraction, config.seed)
        return TripletSource(images, SoundBank.from_corpus(corpus, ("train",)), train_rows, val_rows)

    def _fixed_val_batches(self, source: TripletSource, seed: int) -> list[tuple]:
        """Held-out triplets with their sounds drawn once, so every evaluation sees the same ones."""
        rng = np.random.default_rng([seed, 2])
        rows = source.val_rows
        chunks = [rows[i : i + 512] for i in range(0, len(rows), 512)]
        return [(*source.batch(chunk, rng), source.images.heard[chunk] >= 0) for chunk in chunks]

    def _start_from(self, path: str) -> None:
        payload = read_checkpoint(path)
        try:
            load_state_into(self.model, payload, path)
        except CheckpointMismatchError as error:
            raise CheckpointMismatchError(f"Cannot fine-tune from it: {error}") from error

    # -- checkpoints

    def _last_path(self) -> Path:
        return self.run_dir / "last.pt"

    def save(self, path: Path) -> None:
        save_var(
            self.model,
            path,
            manifest_hash=self.corpus_hash,
            sound_set=self.config.sounds,
            world=self.source.images.meta.get("world"),
            train_config=as_lists(self.config.to_dict()),
            training={
                "step": self.step,
                "optimizer": self.optimizer.state_dict(),
                "scheduler": self.scheduler.state_dict(),
                "rng": _rng_state(self.rng),
                "torch_rng": self.torch_rng.get_state(),
                "torch_global_rng": torch.get_rng_state(),
                "best_val": self.best_val,
                "last_val": self.last_val,
                "evals_since_best": self.evals_since_best,
                "trained_seconds": self.trained_seconds,
            },
        )

    def resume_if_possible(self) -> bool:
        path = self._last_path()
        if not path.is_file():
            return False
        payload = read_checkpoint(path)
        saved = TrainConfig.from_dict(payload.get("train_config", {}))
        mismatched = [
            k
            for k in ("dataset", "sounds", "batch_size", "seed", "replay_dataset", "replay_fraction")
            if getattr(saved, k) != getattr(self.config, k)
        ]
        if mismatched:
            raise CheckpointMismatchError(
                f"{path} belongs to a run with other settings ({', '.join(mismatched)}); use a new --run-dir "
                "or delete the old one."
            )
        load_state_into(self.model, payload, path)
        state = payload["training"]
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.rng.bit_generator.state = state["rng"]
        self.torch_rng.set_state(state["torch_rng"])
        torch.set_rng_state(state["torch_global_rng"])
        self.step, self.best_val, self.last_val = state["step"], state["best_val"], state["last_val"]
        self.evals_since_best, self.trained_seconds = state["evals_since_best"], state["trained_seconds"]
        _truncate_metrics(self.run_dir / "metrics.jsonl", self.step)
        return True

    # -- the loop

    def _rows_for_step(self, step: int) -> np.ndarray:
        """Seeded permutations per pass over each pool, so a resumed run continues exactly where it stopped.

        With `in_view_share`, that share of every batch comes from images with a target in view and the rest
        from images with nothing (or several things) in view; random exploration sees a target only rarely.
        """
        rows = self.source.train_rows
        share = self.config.in_view_share
        if share is None:
            return _stream(rows, self.new_per_batch, step, [self.config.seed, 3])
        heard = self.source.images.heard[rows]
        in_view, nothing = rows[heard >= 0], rows[heard < 0]
        if len(in_view) == 0 or len(nothing) == 0:
            return _stream(rows, self.new_per_batch, step, [self.config.seed, 3])
        count = min(self.new_per_batch - 1, max(1, round(self.new_per_batch * share)))
        return np.concatenate(
            [
                _stream(in_view, count, step, [self.config.seed, 4]),
                _stream(nothing, self.new_per_batch - count, step, [self.config.seed, 5]),
            ]
        )

    def _batch(self, step: int):
        images, positive, negative = self.source.batch(self._rows_for_step(step), self.rng)
        if self.replay:
            replay_rows = self.rng.choice(self.replay.train_rows, self.config.batch_size - self.new_per_batch)
            more = self.replay.batch(replay_rows, self.rng)
            images, positive, negative = (
                np.concatenate(pair) for pair in zip((images, positive, negative), more, strict=True)
            )
        images, positive, negative = (
            torch.from_numpy(images),
            torch.from_numpy(positive),
            torch.from_numpy(negative),
        )
        if self.augment:
            sounds = self.augment(torch.cat([positive, negative]), self.torch_rng)
            positive, negative = sounds.split(len(positive))
            images = augment_images(
                images, self.torch_rng, self.config.image_shift_fraction, self.config.image_jitter
            )
        return images, positive, negative

    def train_step(self, step: int) -> tuple[float, float]:
        images, positive, negative = self._batch(step)
        self.model.train()
        anchor = self.model.encode_image(images)
        sounds = self.model.encode_sound(torch.cat([positive, negative]))
        v_pos, v_neg = sounds.split(len(positive))
        loss = triplet_loss(anchor, v_pos, v_neg, self.config.margin)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.scheduler.step()
        accuracy = triplet_correct(anchor.detach(), v_pos.detach(), v_neg.detach()).float().mean()
        return float(loss.detach()), float(accuracy)

    @torch.inference_mode()
    def evaluate(self, batches: list[tuple]) -> dict[str, float]:
        """Loss, accuracy, and the mean of the accuracies with and without a target in view ("balanced")."""
        self.model.eval()
        losses, correct, in_view = [], [], []
        for images, positive, negative, seen in batches:
            anchor = self.model.encode_image(torch.from_numpy(images))
            v_pos = self.model.encode_sound(torch.from_numpy(positive))
            v_neg = self.model.encode_sound(torch.from_numpy(negative))
            losses.append(triplet_losses(anchor, v_pos, v_neg, self.config.margin).numpy())
            correct.append(triplet_correct(anchor, v_pos, v_neg).numpy())
            in_view.append(seen)
        loss, hit, seen = np.concatenate(losses), np.concatenate(correct), np.concatenate(in_view)
        groups = [hit[mask].mean() for mask in (seen, ~seen) if mask.any()]
        return {"loss": float(loss.mean()), "accuracy": float(hit.mean()), "balanced": float(np.mean(groups))}

    def run(self) -> TrainResult:
        config = self.config
        eval_every = config.eval_every_steps or self.steps_per_epoch
        metrics = (self.run_dir / "metrics.jsonl").open("a")
        losses, accuracies = [], []
        started, stopped_early, interrupted = time.perf_counter(), False, False
        seconds_before = self.trained_seconds
        with tqdm(
            total=self.total_steps,
            initial=self.step,
            desc="train VAR",
            unit="step",
            disable=not config.progress,
        ) as bar:
            while self.step < self.total_steps:
                loss, accuracy = self.train_step(self.step)
                self.step += 1
                losses.append(loss)
                accuracies.append(accuracy)
                bar.update(1)
                self.trained_seconds = seconds_before + time.perf_counter() - started
                record: dict[str, Any] | None = None
                if self.step % config.log_every_steps == 0 or self.step == self.total_steps:
                    record = self._train_record(losses, accuracies)
                    losses, accuracies = [], []
                    _write(metrics, record)
                    bar.set_postfix(loss=f"{record['loss']:.3f}", acc=f"{record['accuracy']:.3f}")
                if self.step % eval_every == 0 or self.step == self.total_steps:
                    record = self._val_record()
                    _write(metrics, record)
                    if config.patience is not None and self.evals_since_best >= config.patience:
                        stopped_early = True
                if self.step % config.checkpoint_every_steps == 0 or stopped_early:
                    self.save(self._last_path())
                if record is not None and self.callback is not None and self.callback(record):
                    interrupted = True
                if stopped_early or interrupted:
                    break
        metrics.close()
        self.save(self._last_path())
        final = self._final_checkpoint()
        plot_training_metrics(self.run_dir / "metrics.jsonl", self.run_dir / "metrics.png")
        return TrainResult(
            run_dir=self.run_dir,
            checkpoint=final,
            steps=self.step,
            epochs_completed=self.step * self.new_per_batch / len(self.source.train_rows),
            seconds=self.trained_seconds,
            triplets_per_second=self.step * config.batch_size / max(self.trained_seconds, 1e-9),
            best_val_accuracy=self.best_val,
            final_val_accuracy=self.last_val,
            stopped_early=stopped_early,
            interrupted=interrupted,
        )

    def _train_record(self, losses: list[float], accuracies: list[float]) -> dict[str, Any]:
        return {
            "kind": "train",
            "step": self.step,
            "epoch": round(self.step / self.steps_per_epoch, 3),
            "loss": float(np.mean(losses)),
            "accuracy": float(np.mean(accuracies)),
            "lr": self.scheduler.get_last_lr()[0],
            "seconds": round(self.trained_seconds, 2),
        }

    def _val_record(self) -> dict[str, Any]:
        record: dict[str, Any] = {
            "kind": "val",
            "step": self.step,
            "epoch": round(self.step / self.steps_per_epoch, 3),
        }
        if self.val_batches:
            scores = self.evaluate(self.val_batches)
            record.update(
                val_loss=scores["loss"],
                val_accuracy=scores["accuracy"],
                val_balanced_accuracy=scores["balanced"],
            )
            self.last_val = scores["balanced"]
            if self.best_val is None or self.last_val > self.best_val:
                self.best_val, self.evals_since_best = self.last_val, 0
                self.save(self.run_dir / "best.pt")
            else:
                self.evals_since_best += 1
        if self.replay_val_batches:
            scores = self.evaluate(self.replay_val_batches)
            record.update(
                replay_val_accuracy=scores["accuracy"], replay_val_balanced_accuracy=scores["balanced"]
            )
        return record

    def _final_checkpoint(self) -> Path:
        """best.pt when a held-out set chose the weights (early stopping), otherwise the last weights."""
        best = self.run_dir / "best.pt"
        final = self.run_dir / "final.pt"
        chosen = best if self.config.patience is not None and best.is_file() else self._last_path()
        payload = read_checkpoint(chosen)
        payload.pop("training", None)
        torch.save(payload, final)
        return final


def train(
    config: TrainConfig, resume: bool = True, callback: Callable[[dict], bool] | None = None
) -> TrainResult:
    """Train (or fine-tune) a VAR. Resumes from `run_dir/last.pt` when it exists and `resume` is set.

    `callback(record)` is called with every logged metrics record; returning True stops the run cleanly after
    saving a checkpoint (how a worker cancels cooperatively).
    """
    trainer = _Trainer(config, callback)
    if resume:
        trainer.resume_if_possible()
    elif (trainer.run_dir / "metrics.jsonl").exists():
        (trainer.run_dir / "metrics.jsonl").unlink()
    return trainer.run()


def plot_training_metrics(metrics_path: Path, png_path: Path) -> Path | None:
    from learning.var.plot import plot_metrics

    return plot_metrics(metrics_path, png_path)


def _stream(pool: np.ndarray, count: int, step: int, seed: list[int]) -> np.ndarray:
    """Rows [step·count, (step+1)·count) of an endless sequence of seeded permutations of `pool`."""
    start, end = step * count, (step + 1) * count
    passes = range(start // len(pool), (end - 1) // len(pool) + 1)
    sequence = np.concatenate([np.random.default_rng([*seed, p]).permutation(pool) for p in passes])
    offset = passes[0] * len(pool)
    return sequence[start - offset : end - offset]


def _write(stream: Any, record: dict[str, Any]) -> None:
    stream.write(json.dumps(record) + "\n")
    stream.flush()


def _truncate_metrics(path: Path, step: int) -> None:
    if not path.is_file():
        return
    kept = [line for line in path.read_text().splitlines() if line and json.loads(line)["step"] <= step]
    path.write_text("".join(line + "\n" for line in kept))


def _rng_state(rng: np.random.Generator) -> dict[str, Any]:
    return rng.bit_generator.state
