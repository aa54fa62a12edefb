"""Fine-tuning a trained VAR on a small set of new triplets (people's own voices, a shifted room).

Same trainer as pre-training, other defaults: start from a checkpoint, a lower learning rate, a larger
held-out share of the new images for early stopping, and optionally a replay sample of the original
triplets in every batch so that the old sounds and rooms are not forgotten.
"""

from pathlib import Path

from learning.front_ends import check_front_end
from learning.var.checkpoint import read_checkpoint
from learning.var.model import VARConfig
from learning.var.train import TrainConfig, TrainResult, train


def finetune_config(
    checkpoint: str | Path,
    dataset: str,
    sounds: str,
    run_dir: str | Path,
    sound_splits: tuple[str, ...] = ("train",),
    sound_speakers: tuple[str, ...] | None = None,
    replay_dataset: str | None = None,
    replay_sounds: str | None = None,
    replay_fraction: float = 0.25,
    front_end: str | None = None,
    **overrides,
) -> TrainConfig:
    """A TrainConfig for fine-tuning `checkpoint`; the model shape comes from the checkpoint itself.
    `front_end`, when given, must be the checkpoint's: a fine-tune keeps its parent's sound front end."""
    payload = read_checkpoint(checkpoint)
    if front_end is not None:
        require_front_end(checkpoint, VARConfig.from_dict(payload["config"]).front_end, front_end)
    settings = dict(
        dataset=dataset,
        sounds=sounds,
        run_dir=str(run_dir),
        sound_splits=sound_splits,
        sound_speakers=sound_speakers,
        model=VARConfig.from_dict(payload["config"]),
        epochs=20,
        lr=3e-4,
        warmup_steps=10,
        val_fraction=0.2,
        patience=3,
        init_checkpoint=str(checkpoint),
        replay_dataset=replay_dataset,
        replay_sounds=replay_sounds or payload.get("sound_set"),
        replay_fraction=replay_fraction if replay_dataset else 0.0,
        log_every_steps=5,
    )
    settings.update(overrides)
    return TrainConfig(**settings)


def require_front_end(checkpoint: str | Path, parent: str, asked: str) -> None:
    """Refuse a fine-tune asked for with another front end than its parent VAR's."""
    check_front_end(asked)
    if asked != parent:
        raise ValueError(
            f"{checkpoint} is a VAR with the {parent!r} sound front end and a fine-tune keeps its parent's: "
            f"leave --front-end out (or give {parent!r}), or train a new VAR with "
            f"`varbot var train --front-end {asked}`."
        )


def finetune(
    checkpoint: str | Path, dataset: str, sounds: str, run_dir: str | Path, **options
) -> TrainResult:
    return train(finetune_config(checkpoint, dataset, sounds, run_dir, **options))
