"""Policy checkpoints: their format version, and how the checkpoints of older versions load.

Format 1 is every checkpoint written before checkpoints carried a `format_version` (the shipped base models,
compacted model versions, the first runs). Some of them predate options of the network and of the run; such a
checkpoint loads with the value it was trained with (`LEGACY_POLICY_OPTIONS`, `LEGACY_RUN_OPTIONS`), never
with today's default. Format 2 adds the version; its settings are complete. A newer format is refused: this
code cannot know what it would have to do with it.

Every reader goes through `read_policy_checkpoint`, which hands back a payload in today's shape. A run's
checkpoint (`write_run_checkpoint`) also holds the optimiser, every RNG state and the statistics, so that
`restore_run` continues it exactly.
"""

import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from learning.rl.policy import Policy, PolicyConfig
from learning.rl.stats import PeakMemory, Timings

if TYPE_CHECKING:
    from learning.rl.ppo import PPOTrainer

CHECKPOINT_KIND = "varbot-policy"
FORMAT_VERSION = 2
UNVERSIONED_FORMAT = 1  # what a checkpoint without `format_version` is

# what checkpoints saved before these options existed were trained with
LEGACY_POLICY_OPTIONS: dict[str, Any] = {"goal_fusion": "core", "bounded_mean": False, "goal_match": False}
LEGACY_RUN_OPTIONS: dict[str, Any] = {**LEGACY_POLICY_OPTIONS, "hard_target_share": 0.0}  # uniform targets


def with_legacy_run_options(settings: dict[str, Any]) -> dict[str, Any]:
    """Run settings saved before some options existed, completed with the values that run used."""
    return {**LEGACY_RUN_OPTIONS, **settings}


def read_policy_checkpoint(path: Path) -> dict[str, Any]:
    """The checkpoint's contents, upgraded to the current format; refuses what is not one of ours."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy checkpoint at {path}; train one with `varbot rl train`")
    payload = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(payload, dict) or payload.get("kind") != CHECKPOINT_KIND:
        raise ValueError(f"{path} is not a varbot policy checkpoint")
    version = payload.get("format_version", UNVERSIONED_FORMAT)
    if version == UNVERSIONED_FORMAT:
        return _upgrade_unversioned(payload)
    if version != FORMAT_VERSION:
        raise ValueError(
            f"{path} is a policy checkpoint of format {version}, but this code reads formats "
            f"{UNVERSIONED_FORMAT} to {FORMAT_VERSION}: it was written by a newer varbot; update to load it"
        )
    return payload


def _upgrade_unversioned(payload: dict[str, Any]) -> dict[str, Any]:
    upgraded = {**payload, "format_version": FORMAT_VERSION}
    upgraded["policy_config"] = {**LEGACY_POLICY_OPTIONS, **payload["policy_config"]}
    if "config" in payload:
        upgraded["config"] = with_legacy_run_options(payload["config"])
    if "stats" in payload and "intents" not in payload["stats"]:
        # the intent of each recent episode was not logged yet: -1 (unknown)
        upgraded["stats"] = {**payload["stats"], "intents": [-1] * len(payload["stats"]["successes"])}
    return upgraded


ACTING_KEYS = ("kind", "format_version", "config", "policy_config", "policy", "label_counts")


def compact_policy_checkpoint(source: Path, out: Path) -> Path:
    """The policy without optimiser, RNG and episode state, in the current format: what a model version or
    a base model needs to act and to improve."""
    torch.save(_acting_part(read_policy_checkpoint(source)), out)
    return out


def _acting_part(payload: dict[str, Any]) -> dict[str, Any]:
    return {key: payload[key] for key in ACTING_KEYS if key in payload}


def policy_with_view(source: Path, view_state: dict[str, torch.Tensor], out: Path) -> Path:
    """A compact copy of the policy at `source` whose frozen VAR view (`var_view.encoder`) holds `view_state`,
    an image encoder's weights of the same shape; everything else is the policy's own."""
    payload = read_policy_checkpoint(source)
    prefix = "var_view.encoder."
    own = {key[len(prefix) :] for key in payload["policy"] if key.startswith(prefix)}
    if own != set(view_state):
        raise ValueError(
            f"{source} holds no policy that sees through a VAR of this shape (policy_view='var')"
        )
    weights = {**payload["policy"], **{prefix + key: value for key, value in view_state.items()}}
    torch.save({**_acting_part(payload), "policy": weights}, out)
    return out


def load_policy(path: Path) -> tuple[Policy, dict[str, Any]]:
    """The policy stored in a checkpoint (eval mode) and the checkpoint's contents."""
    payload = read_policy_checkpoint(path)
    policy = Policy(PolicyConfig(**payload["policy_config"]))
    policy.load_state_dict(payload["policy"])
    return policy.eval(), payload


def load_initial_policy(policy: Policy, path: Path) -> None:
    """Start a run from the weights of an earlier one (self-improvement); the networks must be the same."""
    payload = read_policy_checkpoint(path)
    if PolicyConfig(**payload["policy_config"]) != policy.config:
        raise ValueError(
            f"{path} holds a policy for {payload['policy_config']}, this run needs {policy.config.to_dict()}"
        )
    policy.load_state_dict(payload["policy"])


def write_run_checkpoint(trainer: "PPOTrainer", path: Path) -> Path:
    """Atomically to `path`; at every `checkpoint_every` updates also to a numbered copy beside it."""
    payload = {
        "kind": CHECKPOINT_KIND,
        "format_version": FORMAT_VERSION,
        "config": asdict(trainer.config),
        "policy_config": trainer.policy.config.to_dict(),
        "policy": trainer.policy.state_dict(),
        "optimizer": trainer.optimizer.state_dict(),
        "update_index": trainer.update_index,
        "global_step": trainer.global_step,
        "return_rms": trainer.normalise.rms.state(),
        "numpy_rng": trainer.rng.bit_generator.state,
        "torch_rng": trainer.torch_rng.get_state(),
        "stats": {k: list(v) for k, v in vars(trainer.stats).items()},
        "timings": asdict(trainer.timings),
        "peak_memory_bytes": trainer.memory.peak_bytes,
        "var_path": trainer.var_path,
        "label_counts": trainer.label_counts,
    }
    temporary = path.with_name(path.name + ".tmp")
    torch.save(payload, temporary)
    os.replace(temporary, path)
    if trainer.update_index % trainer.config.checkpoint_every == 0:
        torch.save(payload, trainer.run_dir / f"checkpoint_{trainer.update_index:06d}.pt")
    return path


def restore_run(trainer: "PPOTrainer", path: Path) -> None:
    """Everything `write_run_checkpoint` saved, back into a started trainer; the metrics of updates made after
    the checkpoint are dropped."""
    payload = read_policy_checkpoint(path)
    trainer.policy.load_state_dict(payload["policy"])
    trainer.optimizer.load_state_dict(payload["optimizer"])
    trainer.update_index = payload["update_index"]
    trainer.global_step = payload["global_step"]
    trainer.normalise.rms.load(payload["return_rms"])
    trainer.rng.bit_generator.state = payload["numpy_rng"]
    trainer.torch_rng.set_state(payload["torch_rng"])
    stats = payload["stats"]
    for key in vars(trainer.stats):
        missing = [trainer.stats.unknown(key)] * len(stats["successes"])  # a field newer than the checkpoint
        getattr(trainer.stats, key).extend(stats.get(key, missing))
    trainer.timings = Timings(**payload["timings"])
    trainer.memory = PeakMemory(payload["peak_memory_bytes"])
    trainer.label_counts = payload.get("label_counts", trainer.label_counts)
    trainer.needs_reset = True
    metrics = trainer.run_dir / "metrics.jsonl"
    if metrics.exists():
        lines = metrics.read_text().splitlines()
        kept = [line for line in lines if json.loads(line)["update"] <= trainer.update_index]
        metrics.write_text("".join(line + "\n" for line in kept))
