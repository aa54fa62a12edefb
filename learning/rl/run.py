"""Build and run a training run from names: a world, a sound corpus, a VAR checkpoint, a method.

Used by `varbot rl train`, `varbot rl improve`, `bench/reproduce.py` and (later) the Celery worker. A run
lives in one directory: `config.json`, `checkpoint.pt` (+ periodic `checkpoint_NNNNNN.pt`), `metrics.jsonl`,
`curves.png`.
"""

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from learning.rl.ppo import PPOConfig, PPOTrainer, RolloutStep
from learning.rl.rewards import ClipBank, corpus_bank


def load_frozen_var(path: str | Path | None) -> torch.nn.Module | None:
    if path is None:
        return None
    from learning.var.checkpoint import load_var

    return load_var(path).eval().requires_grad_(False)


def var_label_count(var_path: str | Path | None) -> dict[str, int]:
    """Labels behind a VAR, counted as the paper does: 2 per triplet of the dataset it was trained on."""
    if var_path is None:
        return {}
    from core.paths import data_dir
    from learning.var.checkpoint import read_checkpoint

    payload = read_checkpoint(var_path)
    dataset = (payload.get("train_config") or {}).get("dataset")
    if not dataset:
        return {}
    for folder in (Path(dataset), data_dir() / "var" / "datasets" / dataset):
        meta = folder / "meta.json"
        if meta.is_file():
            return {"var_triplet_labels": 2 * int(json.loads(meta.read_text())["count"])}
    return {}


def make_trainer(
    config: PPOConfig,
    run_dir: Path,
    var_path: str | Path | None,
    goals: ClipBank | None = None,
    init_policy: Path | None = None,
    resume: bool = False,
) -> PPOTrainer:
    """A started trainer (workers running). With `resume`, continue from `run_dir/checkpoint.pt` if present;
    the stored config must then match the given one except for `total_steps` (which may grow)."""
    run_dir = Path(run_dir)
    checkpoint = run_dir / "checkpoint.pt"
    if resume and checkpoint.exists():
        saved = json.loads((run_dir / "config.json").read_text())
        saved = asdict(PPOConfig.from_dict(saved))
        mine = {k: v for k, v in asdict(config).items() if k != "total_steps"}
        differs = {k: (saved.get(k), v) for k, v in mine.items() if saved.get(k) != v}
        if differs:
            raise ValueError(
                f"{run_dir} was started with other settings ({differs}); "
                "use a new run directory or the same settings"
            )
    elif checkpoint.exists() and not resume:
        raise FileExistsError(
            f"{run_dir} already holds a run; pass --resume to continue it or choose another --run-dir"
        )
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(json.dumps({**asdict(config), "var_path": str(var_path)}, indent=2))
    var = load_frozen_var(var_path)
    front_end = var.front_end if var is not None else "mfcc"  # goal clips as the VAR's f_S reads them
    if goals is None:
        goals = corpus_bank(config.sounds, config.goal_split, front_end=front_end)
    current = corpus_bank(config.sounds, "train", front_end=front_end) if config.current_sound else None
    trainer = PPOTrainer(
        config,
        run_dir,
        var,
        goals,
        current_sounds=current,
        init_policy=init_policy,
        var_path=None if var_path is None else str(var_path),
        label_counts=var_label_count(var_path) if config.goal_encoder == "var" else {},
    )
    trainer.start()
    if resume and checkpoint.exists():
        trainer.load_checkpoint(checkpoint)
    return trainer


def train_run(
    config: PPOConfig,
    run_dir: Path,
    var_path: str | Path | None,
    goals: ClipBank | None = None,
    init_policy: Path | None = None,
    resume: bool = False,
    progress: bool = True,
    on_update: Callable[[dict[str, Any]], bool | None] | None = None,
    on_rollout_step: Callable[[RolloutStep], None] | None = None,
) -> dict[str, Any]:
    from learning.rl.plots import plot_run

    trainer = make_trainer(config, run_dir, var_path, goals, init_policy, resume)
    try:
        summary = trainer.train(progress=progress, on_update=on_update, on_rollout_step=on_rollout_step)
    finally:
        trainer.close()
    plot_run(Path(run_dir))
    (Path(run_dir) / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
