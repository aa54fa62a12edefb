"""The pre-trained base models a new household starts from (VAR + policy per simulated world).

Looked up in order: `$VARBOT_BASE_MODELS_DIR/<world>/`, `data_dir()/base_models/<world>/` (what
`varbot models build-base` writes by default), then the copies shipped in the repository
(`worker/base_models/<world>/`). Each folder holds `var.pt`, `policy.pt` and `base.json` (the command and the
figures that made them).
"""

import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.paths import REPO_ROOT, data_dir

SHIPPED_DIR = REPO_ROOT / "worker" / "base_models"
RECORD = "base.json"


class BaseModelMissing(FileNotFoundError):
    pass


@dataclass(frozen=True)
class BaseModel:
    world: str
    folder: Path

    @property
    def var_path(self) -> Path:
        return self.folder / "var.pt"

    @property
    def policy_path(self) -> Path:
        return self.folder / "policy.pt"

    @property
    def record(self) -> dict[str, Any]:
        path = self.folder / RECORD
        return json.loads(path.read_text()) if path.is_file() else {}

    @property
    def image_size(self) -> int:
        return int(self.record.get("image_size", 96))

    @property
    def feature_kind(self) -> str:
        return str(self.record.get("feature_kind", "speech"))


def search_path() -> list[Path]:
    env = os.environ.get("VARBOT_BASE_MODELS_DIR")
    return [*([Path(env)] if env else []), data_dir() / "base_models", SHIPPED_DIR]


def find_base(world: str) -> BaseModel:
    for root in search_path():
        folder = root / world
        if (folder / "var.pt").is_file() and (folder / "policy.pt").is_file():
            return BaseModel(world, folder)
    raise BaseModelMissing(
        f"no base model for the {world} world in {', '.join(map(str, search_path()))}; "
        f"build one with `varbot models build-base --world {world}`"
    )


def write_base(
    world: str, var_checkpoint: Path, policy_checkpoint: Path, out_root: Path, record: dict
) -> Path:
    """Copy a VAR and a policy into `out_root/<world>/` (the policy without optimiser state) with a record."""
    import torch

    from learning.rl.ppo import read_policy_checkpoint
    from learning.var.checkpoint import read_checkpoint

    folder = out_root / world
    folder.mkdir(parents=True, exist_ok=True)
    var_payload = read_checkpoint(var_checkpoint)
    var_payload.pop("training", None)
    torch.save(var_payload, folder / "var.pt")
    policy = read_policy_checkpoint(policy_checkpoint)
    kept = {
        k: policy[k] for k in ("kind", "config", "policy_config", "policy", "label_counts") if k in policy
    }
    torch.save(kept, folder / "policy.pt")
    sizes = {name: (folder / name).stat().st_size for name in ("var.pt", "policy.pt")}
    (folder / RECORD).write_text(json.dumps({**record, "file_bytes": sizes}, indent=2) + "\n")
    return folder


def build_base(
    world: str,
    sounds: str,
    views: int,
    image_size: int,
    var_epochs: int,
    policy_steps: int,
    eval_episodes_per_intent: int,
    out_root: Path,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Collect views → train the VAR → train the policy with the intrinsic reward → evaluate → write."""
    from learning.rl.evaluate import evaluate
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank
    from learning.rl.run import train_run
    from learning.sounds import load_corpus
    from learning.var.checkpoint import load_var
    from learning.var.dataset import collect_dataset
    from learning.var.train import TrainConfig, train

    work = data_dir() / "base_build" / f"{world}-{sounds}-{views}-{image_size}px-seed{seed}"
    timings: dict[str, float] = {}
    tick = time.perf_counter()
    dataset = collect_dataset(
        world, views, f"base-{world}-{views}-{image_size}px-seed{seed}", seed=seed, image_size=image_size,
        progress=progress,
    )  # fmt: skip
    timings["collect_s"] = round(time.perf_counter() - tick, 1)
    tick = time.perf_counter()
    var_result = train(
        TrainConfig(
            dataset=str(dataset.path), sounds=sounds, run_dir=str(work / "var"), epochs=var_epochs,
            seed=seed, threads=1, progress=progress,
        )
    )  # fmt: skip
    timings["var_train_s"] = round(time.perf_counter() - tick, 1)
    tick = time.perf_counter()
    ppo = PPOConfig(world=world, sounds=sounds, image_size=image_size, total_steps=policy_steps, seed=seed)
    policy_dir = work / "policy"
    summary = train_run(ppo, policy_dir, var_result.checkpoint, resume=True, progress=progress)
    timings["policy_train_s"] = round(time.perf_counter() - tick, 1)
    tick = time.perf_counter()
    corpus = load_corpus(sounds)
    unheard = [s for s in corpus.splits if s != "train"]
    var = load_var(var_result.checkpoint)
    policy, _ = load_policy(policy_dir / "checkpoint.pt")
    evaluations = {}
    for split in unheard[:1]:
        goals = corpus_bank(sounds, split, front_end=var.front_end).embed(var)
        result = evaluate(
            policy, var, goals, world, image_size, split=split,
            episodes_per_intent=eval_episodes_per_intent, seed=seed + 999, progress=progress,
        )  # fmt: skip
        evaluations[split] = {"success_rate": result.success_rate, "episodes": len(result.episodes)}
    timings["evaluate_s"] = round(time.perf_counter() - tick, 1)
    record = {
        "world": world,
        "sounds": sounds,
        "feature_kind": corpus.kind,
        "image_size": image_size,
        "command": " ".join(["varbot", "models", "build-base", *sys.argv[3:]])
        if "build-base" in sys.argv
        else None,
        "views": views,
        "var_epochs": var_epochs,
        "var_best_val_balanced_accuracy": var_result.best_val_accuracy,
        "var_final_val_balanced_accuracy": var_result.final_val_accuracy,
        "policy_env_steps": summary["env_steps"],
        "policy_recent_success_in_training": summary["recent_success"],
        "evaluation": evaluations,
        "timings": timings,
        "built_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    folder = write_base(world, var_result.checkpoint, policy_dir / "checkpoint.pt", out_root, record)
    for source, name in (
        (work / "var" / "metrics.png", "var_curves.png"),
        (policy_dir / "curves.png", "policy_curves.png"),
    ):
        if source.is_file():
            shutil.copy(source, folder / name)
    return record
