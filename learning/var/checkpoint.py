"""VAR checkpoints: weights + the config that fixes their shape (the sound front end included) + whatever the
trainer needs to resume.

One file serves both uses: `load_var` reads the model for inference, `read_checkpoint` the training state.
"""

import os
from pathlib import Path
from typing import Any

import torch

from learning.var.model import VAR, VARConfig

CHECKPOINT_KIND = "varbot-var"
FORMAT_VERSION = 1


class CheckpointMismatchError(ValueError):
    """The checkpoint does not fit the model or the sound corpus it is being used with."""


def save_var(model: VAR, path: str | Path, **extra: Any) -> Path:
    """Write weights, config and `extra` (e.g. manifest_hash, training state) atomically to `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "kind": CHECKPOINT_KIND,
        "format_version": FORMAT_VERSION,
        "config": model.config.to_dict(),
        "state_dict": model.state_dict(),
        **extra,
    }
    temporary = path.with_name(path.name + ".tmp")
    torch.save(payload, temporary)
    os.replace(temporary, path)
    return path


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No VAR checkpoint at {path}; train one with `varbot var train`.")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several unrelated types for a corrupt file
        raise CheckpointMismatchError(f"{path} is not a readable VAR checkpoint ({error}).") from error
    if not isinstance(payload, dict) or payload.get("kind") != CHECKPOINT_KIND:
        raise CheckpointMismatchError(f"{path} is not a VAR checkpoint (written by something else).")
    if payload.get("format_version") != FORMAT_VERSION:
        raise CheckpointMismatchError(
            f"{path} has checkpoint format {payload.get('format_version')}, this code reads {FORMAT_VERSION}."
        )
    return payload


def _config_differences(expected: VARConfig, found: VARConfig) -> list[str]:
    mine, theirs = expected.to_dict(), found.to_dict()
    return [
        _front_end_difference(expected.front_end, found.front_end)
        if key == "front_end"
        else f"{key}: model has {mine[key]}, checkpoint has {theirs[key]}"
        for key in mine
        if mine[key] != theirs[key]
    ]


def _front_end_difference(wanted: str, saved: str) -> str:
    return (
        f"sound front end: the checkpoint's f_S reads '{saved}' features, but '{wanted}' features are used "
        f"here (compute the clips' features with front_end='{saved}', or train a VAR on '{wanted}')"
    )


def front_end_of(path: str | Path) -> str:
    """The sound front end of the VAR at `path`: what its clips' features must be computed with."""
    return VARConfig.from_dict(read_checkpoint(path)["config"]).front_end


def check_front_end(payload: dict[str, Any], front_end: str | None, path: str | Path) -> None:
    """Refuse a checkpoint whose sound front end is not the one the caller's features come from."""
    saved = VARConfig.from_dict(payload["config"]).front_end
    if front_end is not None and saved != front_end:
        raise CheckpointMismatchError(f"{path} does not fit: {_front_end_difference(front_end, saved)}.")


def check_manifest(payload: dict[str, Any], manifest_hash: str | None, path: str | Path) -> None:
    saved = payload.get("manifest_hash")
    if manifest_hash is not None and saved is not None and saved != manifest_hash:
        raise CheckpointMismatchError(
            f"{path} was trained with sound corpus '{payload.get('sound_set')}' whose manifest hash is "
            f"{saved[:12]}, but the corpus given now has hash {manifest_hash[:12]}. Rebuild the same corpus, "
            "or retrain/fine-tune the VAR on this one."
        )


def load_state_into(model: VAR, payload: dict[str, Any], path: str | Path) -> None:
    """Copy the checkpoint's weights into `model`, refusing with a clear message if the shapes differ."""
    found = VARConfig.from_dict(payload["config"])
    differences = _config_differences(model.config, found)
    if differences:
        raise CheckpointMismatchError(
            f"{path} does not fit this VAR: " + "; ".join(differences) + ". Build the model from the "
            "checkpoint's own config (load_var does) or train a new checkpoint."
        )
    model.load_state_dict(payload["state_dict"])


def load_var(
    path: str | Path,
    config: VARConfig | None = None,
    manifest_hash: str | None = None,
    front_end: str | None = None,
) -> VAR:
    """The VAR stored at `path`, in eval mode; with `config`/`manifest_hash`/`front_end`, refuse one that
    differs. A checkpoint written before front ends existed is an MFCC one."""
    payload = read_checkpoint(path)
    check_manifest(payload, manifest_hash, path)
    check_front_end(payload, front_end, path)
    model = VAR(config or VARConfig.from_dict(payload["config"]))
    load_state_into(model, payload, path)
    return model.eval()
