"""Build and run a training run from names: a world, a sound corpus, a VAR checkpoint, a method.

Used by `varbot rl train`, `varbot rl improve`, `bench/reproduce.py` and (later) the Celery worker. A run
lives in one directory: `config.json`, `checkpoint.pt` (+ periodic `checkpoint_NNNNNN.pt`, the policy it
started from as `checkpoint_000000.pt`), `metrics.jsonl`, `curves.png`.
"""

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from learning.rl.frozen_var import LoadedVar, load_frozen_var
from learning.rl.ppo import PPOConfig, PPOTrainer, RolloutStep
from learning.rl.rewards import ClipBank, corpus_bank

VarSource = str | Path | LoadedVar | None  # a VAR checkpoint's path, or the VAR already loaded from one


def as_loaded_var(var: VarSource) -> LoadedVar | None:
    return var if isinstance(var, LoadedVar) or var is None else load_frozen_var(var)


def make_trainer(
    config: PPOConfig,
    run_dir: Path,
    var_path: VarSource,
    goals: ClipBank | None = None,
    init_policy: Path | None = None,
    resume: bool = False,
    device: str | torch.device = "cpu",
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
    var = as_loaded_var(var_path)
    run_dir.mkdir(parents=True, exist_ok=True)
    saved_path = str(var.path if var is not None else None)
    started_from = str(init_policy) if init_policy is not None else None
    (run_dir / "config.json").write_text(
        json.dumps({**asdict(config), "var_path": saved_path, "init_policy": started_from}, indent=2)
    )
    front_end = var.model.front_end if var is not None else "mfcc"  # goal clips as the VAR's f_S reads them
    if goals is None:
        goals = corpus_bank(config.sounds, config.goal_split, front_end=front_end)
    current = corpus_bank(config.sounds, "train", front_end=front_end) if config.current_sound else None
    trainer = PPOTrainer(
        config, run_dir, var, goals, current_sounds=current, init_policy=init_policy, device=device
    )
    trainer.start()
    if resume and checkpoint.exists():
        trainer.load_checkpoint(checkpoint)
    return trainer


def train_run(
    config: PPOConfig,
    run_dir: Path,
    var_path: VarSource,
    goals: ClipBank | None = None,
    init_policy: Path | None = None,
    resume: bool = False,
    progress: bool = True,
    on_update: Callable[[dict[str, Any]], bool | None] | None = None,
    on_rollout_step: Callable[[RolloutStep], None] | None = None,
    device: str | torch.device = "cpu",
) -> dict[str, Any]:
    """`device`: where the VAR and the policy run (`learning.device.resolve_device`)."""
    from learning.rl.plots import plot_run

    trainer = make_trainer(config, run_dir, var_path, goals, init_policy, resume, device)
    try:
        summary = trainer.train(progress=progress, on_update=on_update, on_rollout_step=on_rollout_step)
    finally:
        trainer.close()
    plot_run(Path(run_dir))
    (Path(run_dir) / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
