"""Self-improvement after deployment (paper, Sec. IV-D): continue PPO from a trained policy with a fine-tuned
VAR, sampling goals from the household's own recordings, for a step budget. The reward stays intrinsic; no
labels.

Goal clips are `[INTENT:]PATH` entries (WAV/audio or .npy MFCC features). When intents are given the goal of
each episode matches the world's target, so the success rate in the metrics means something; without them
goals are drawn uniformly and the success rate is reported as NaN (training is unaffected: the reward never
reads it).
"""

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from learning.rl.ppo import PPOConfig, read_policy_checkpoint
from learning.rl.rewards import ClipBank, clip_bank_from_paths
from learning.rl.run import train_run
from learning.var.checkpoint import front_end_of


def improve(
    policy_checkpoint: Path,
    var_path: Path,
    goals: ClipBank | list[str],
    steps: int,
    run_dir: Path,
    learning_rate: float | None = None,
    resume: bool = False,
    progress: bool = True,
    on_update: Callable[[dict[str, Any]], bool | None] | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    payload = read_policy_checkpoint(policy_checkpoint)
    base = PPOConfig.from_dict(payload["config"])
    if base.goal_encoder != "var":
        raise ValueError("self-improvement needs a policy trained with the VAR (method `var`)")
    bank = goals if isinstance(goals, ClipBank) else clip_bank_from_paths(goals, front_end_of(var_path))
    batch = base.num_envs * base.num_steps
    if steps < batch:
        raise ValueError(f"the step budget ({steps}) is smaller than one PPO update ({batch} steps)")
    config = dataclasses.replace(
        base,
        total_steps=int(steps),
        learning_rate=learning_rate if learning_rate is not None else base.learning_rate / 3,
        goal_split="household",
        **overrides,
    )
    return train_run(
        config,
        run_dir,
        var_path,
        goals=bank,
        init_policy=policy_checkpoint,
        resume=resume,
        progress=progress,
        on_update=on_update,
    )
