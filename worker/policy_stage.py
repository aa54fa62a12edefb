"""Stage 2: the policy improves itself with the intrinsic reward only (paper, Sec. IV-D): PPO continues from
the parent policy, the VAR (fine-tuned or the parent's) frozen, goals sampled from the household's own clips.

`learning.rl.run.train_run` does the work (environments in subprocesses, checkpoints that resume exactly);
this module builds its configuration as `learning.rl.improve` does, plus the cancel/progress hook and the
live-rollout hook (`worker.live`)."""

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from backend.schemas import RunParams
from worker.household import HouseholdData

if TYPE_CHECKING:
    from core.rooms import DomainShift, RoomRanges
    from learning.rl.ppo import PPOConfig


@dataclass
class PolicyImproveResult:
    checkpoint: Path
    env_steps: int
    updates: int
    recent_success: float | None
    summary: dict[str, Any]


def goal_rows(data: HouseholdData, num_intents: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Which of the household's clips are goals, and their intents. With an inferred intent for every intent
    of the world, each episode's goal names the world's target (so the training success rate means
    something); otherwise all clips are goals, drawn uniformly (intent -1) — the intrinsic reward never reads
    the intent either way."""
    known = set(data.clip_intent[data.clip_intent >= 0].tolist())
    if known >= set(range(num_intents)):
        rows = np.flatnonzero(data.clip_intent >= 0)
        return rows, data.clip_intent[rows]
    return np.arange(len(data.clip_intent)), np.full(len(data.clip_intent), -1, dtype=np.int64)


def goal_bank(data: HouseholdData, num_intents: int = 4):  # type: ignore[no-untyped-def]
    """The household's goal clips (`goal_rows`) as the trainer's goal bank."""
    from learning.rl.rewards import ClipBank

    rows, intents = goal_rows(data, num_intents)
    return ClipBank(data.features[rows], intents)


def goal_clip_ids(data: HouseholdData, num_intents: int = 4) -> np.ndarray:
    """Clip id of each entry of `goal_bank(data)`: the scene marks the clip env 0 is working toward."""
    rows, _intents = goal_rows(data, num_intents)
    return data.clip_ids[rows]


def improvement_config(
    base: "PPOConfig",
    steps: int,
    seed: int,
    room: "DomainShift | None",
    robot_env_context: str | None,
    replay_share: float = 0.0,
    base_ranges: "RoomRanges | None" = None,
    view_follows_var: bool = RunParams.model_fields["policy_view_follows_var"].default,
    learning_rate_scale: float = RunParams.model_fields["policy_learning_rate_scale"].default,
) -> "PPOConfig":
    """The parent's PPO settings, continued for `steps` in the household's room (or on its real robot) with
    the household's clips as goals, at `learning_rate_scale` times the base model's learning rate: a parent
    that is itself a household's fine-tune already runs at its rate, so a second and third fine-tune keep it.

    In simulation `replay_share` of the environments keep practising in the base model's own rooms (for the
    shipped bases, a new room per episode from the training ranges), so that what the base learnt there is
    not lost to the household's one room. A base trained over "randomised" rooms replays `base_ranges`, the
    ranges its record says it was trained over, when given: today's ranges may have grown since.
    `view_follows_var`: a policy that sees through the VAR sees through the run's (the household's) VAR
    instead of its own copy of the base VAR, so that the room the household's VAR learnt reaches the policy
    too (bench/results/household_varview_follows_*.json: the training room kept 83.0 % where the frozen copy
    fell to 59.5 %); a policy with its own CNN is unaffected."""
    from core.rooms import RANDOMISED_ROOMS, ranges_setting, room_setting
    from learning.rl.env_groups import IN_PROCESS
    from learning.rl.ppo import PPOConfig

    from_base = base.goal_split != "household"
    replay_room = base.room if from_base else base.replay_room
    if from_base and replay_room == RANDOMISED_ROOMS and base_ranges is not None:
        replay_room = ranges_setting(base_ranges)
    replay_envs = round(replay_share * base.num_envs)
    if robot_env_context is not None:
        replay_envs = 0
        base = dataclasses.replace(
            base, num_envs=1, env_groups=1, num_minibatches=1, env_context=robot_env_context
        )
    elif base.env_context.startswith(IN_PROCESS):  # the parent improved on a real robot: back to simulation
        base = dataclasses.replace(base, env_context=PPOConfig.env_context)
    return dataclasses.replace(
        base,
        total_steps=max(int(steps), base.batch_size),  # at least one PPO update
        learning_rate=base.learning_rate * learning_rate_scale if from_base else base.learning_rate,
        goal_split="household",
        seed=seed,
        current_sound=False,
        room=room_setting(room),
        replay_envs=replay_envs,
        replay_room=replay_room,
        policy_view_follows_var=view_follows_var and base.policy_view == "var",
    )


def improve_policy(
    data: HouseholdData,
    policy_checkpoint: Path,
    var_checkpoint: Path,
    steps: int,
    work_dir: Path,
    seed: int,
    on_update: Callable[[float, dict[str, Any]], bool],
    on_rollout_step: Callable[[Any], None] | None = None,
    robot_env_context: str | None = None,
    room: "DomainShift | None" = None,
    replay_share: float = 0.0,
    base_ranges: "RoomRanges | None" = None,
    view_follows_var: bool = RunParams.model_fields["policy_view_follows_var"].default,
    learning_rate_scale: float = RunParams.model_fields["policy_learning_rate_scale"].default,
) -> PolicyImproveResult:
    """PPO from `policy_checkpoint`; `on_update(fraction, point)` after each update (True: stop),
    `on_rollout_step` after each step of env 0 (`learning.rl.ppo.RolloutStep`: the live view). With
    `robot_env_context` (`learning.rl.env_groups.in_process_env`: a real robot), PPO runs on that one
    environment in this process instead of simulated worlds; simulated worlds are in `room`, the robot's own
    (None: the training room), but for `replay_share` of the environments, which practise in the base
    model's rooms (`improvement_config`, with `base_ranges`, `view_follows_var` and `learning_rate_scale`).
    The VAR and the policy run where the worker's VARBOT_DEVICE says (`learning.device.resolve_device`)."""
    from backend.settings import get_settings
    from learning.device import resolve_device
    from learning.rl.ppo import PPOConfig, read_policy_checkpoint
    from learning.rl.run import train_run

    device = resolve_device(get_settings().device)  # before anything starts: a missing GPU fails at once
    base = PPOConfig.from_dict(read_policy_checkpoint(policy_checkpoint)["config"])
    if base.goal_encoder != "var":
        raise ValueError(f"{policy_checkpoint} was not trained with the VAR; it cannot improve itself")
    config = improvement_config(
        base,
        steps,
        seed,
        room,
        robot_env_context,
        replay_share,
        base_ranges,
        view_follows_var,
        learning_rate_scale,
    )
    updates_total = config.num_updates

    def hook(record: dict[str, Any]) -> bool:
        point = {
            "update": record["update"],
            "env_steps": record["global_step"],
            "episode_return": _number(record.get("episode_return")),
            "recent_success": _number(record.get("recent_success")),
            "own_room_success": _number(own_room_success(record)),
            "sps": _number(record.get("sps")),
        }
        return on_update(record["update"] / updates_total, point)

    summary = train_run(
        config,
        work_dir,
        var_checkpoint,
        goals=goal_bank(data),
        init_policy=policy_checkpoint,
        resume=True,
        progress=False,
        on_update=hook,
        on_rollout_step=on_rollout_step,
        device=device,
    )
    if int(summary["updates"]) < updates_total:
        from worker.progress import Cancelled

        raise Cancelled("cancel requested during the policy self-improvement")
    return PolicyImproveResult(
        checkpoint=work_dir / "checkpoint.pt",
        env_steps=int(summary["env_steps"]),
        updates=int(summary["updates"]),
        recent_success=_number(summary.get("recent_success")),
        summary=summary,
    )


def success_by_room(summary: dict[str, Any]) -> dict[str, float | None]:
    """The summary's recent success in the household's room and in the replay room (empty without replay)."""
    return {room: _number(value) for room, value in summary.get("recent_success_by_room", {}).items()}


def own_room_success(record: dict[str, Any]) -> Any:
    """An update's recent success in the household's room: all of its environments without replay."""
    by_room = record.get("recent_success_by_room")
    return by_room["own_room"] if by_room else record.get("recent_success")


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None
