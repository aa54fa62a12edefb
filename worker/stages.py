"""The three stages of a run, as the run lifecycle (`worker.pipeline`) calls them: each reads the run's
context, reports progress (which also answers whether a cancel was asked for) and returns its result for
`state.json`. The work itself is `worker.var_stage`, `worker.policy_stage` and `worker.evaluation`."""

import contextlib
import math
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from worker.evaluation import ModelScore, score_model
from worker.progress import Cancelled, Progress
from worker.run_context import RunContext, materialise, materialise_optional, run_param
from worker.var_stage import Diverged

EVAL_NUM_ENVS = int(os.environ.get("VARBOT_EVAL_NUM_ENVS", 4))


def var_finetune(context: RunContext, progress: Progress) -> dict[str, Any]:
    """The household's triplets plus a replay of the simulated training room (`worker.replay`)."""
    from worker.replay import with_replay
    from worker.var_stage import finetune_var

    params = context.params
    fraction = float(run_param(params, "replay_fraction"))
    block_ends_share = float(run_param(params, "replay_block_ends_share"))
    data, replayed = with_replay(
        context.data, context.start_var, context.world, fraction, params["seed"], block_ends_share
    )

    def on_epoch(fraction: float, record: dict[str, Any]) -> bool:
        return progress.update(fraction, {"var": record}, point=record)

    result = finetune_var(
        data,
        context.start_var,
        context.folder / "var",
        epochs=params["var_epochs"],
        batch_size=params["var_batch_size"],
        learning_rate=params["var_learning_rate"],
        seed=params["seed"],
        on_epoch=on_epoch,
        keep_view=float(run_param(params, "var_keep_view")),
    )
    done = {k: str(v) if isinstance(v, Path) else v for k, v in asdict(result).items()}
    return {**done, "train_triplets": len(context.data.train_triplets), "replay_triplets": replayed}


def policy_improve(context: RunContext, progress: Progress) -> dict[str, Any]:
    """In the robot's simulated world, or on the arm itself for a real arm (`worker.real_arm`); in
    simulation the candidate is then chosen among the run's checkpoints (`worker.policy_selection`)."""
    from worker.policy_stage import improve_policy, success_by_room
    from worker.real_arm import arm_env_context

    if context.start_policy is None:
        raise ValueError(f"model version {context.parent_id} has no policy to improve")
    ppo_share = 1.0 - _selection_share(context.params)

    def on_update(fraction: float, point: dict[str, Any]) -> bool:
        for key, value in point.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise Diverged(f"{key} became {value} at PPO update {point['update']}")
        return progress.update(fraction * ppo_share, {"policy": point}, point=point)

    with arm_env_context(context) as on_arm, _live_rollouts(context, "policy_improve", on_arm) as live:
        result = improve_policy(
            context.data,
            context.start_policy,
            context.candidate_var(),
            context.params["policy_steps"],
            context.folder / "policy",
            context.params["seed"],
            on_update,
            live,
            on_arm,
            context.room,
            float(run_param(context.params, "policy_replay_share")),
            context.parent_base_ranges,
            bool(run_param(context.params, "policy_view_follows_var")),
            float(run_param(context.params, "policy_learning_rate_scale")),
        )
    chosen, selection = _choose_policy(context, progress, result.checkpoint, ppo_share, on_arm is not None)
    compact = context.folder / "policy" / "final.pt"
    _compact_policy(chosen, compact)
    return {
        "checkpoint": str(compact),
        "env_steps": result.env_steps,
        "updates": result.updates,
        "recent_success": result.recent_success,
        "recent_success_by_room": success_by_room(result.summary),
        "time_shares": result.summary.get("time_shares"),
        "selection": selection,
    }


def _selection_share(params: dict[str, Any]) -> float:
    """The part of the policy stage's time that choosing among its checkpoints takes (the budget's costs)."""
    from backend.schemas import RunParams
    from backend.services.runs import (
        SECONDS_PER_POLICY_STEP,
        SECONDS_PER_VALIDATION_EPISODE,
        selection_episodes,
    )

    episodes = selection_episodes(RunParams(**params))
    choosing = episodes * SECONDS_PER_VALIDATION_EPISODE
    return choosing / (choosing + params["policy_steps"] * SECONDS_PER_POLICY_STEP) if episodes else 0.0


def _choose_policy(
    context: RunContext, progress: Progress, last: Path, ppo_share: float, on_arm: bool
) -> tuple[Path, dict[str, Any] | str]:
    """The checkpoint that becomes the candidate's policy, and the selection's record (or why there was
    none): `worker.policy_selection` in simulation when the run asks for validation episodes."""
    from worker.policy_selection import PolicyScore, select_policy

    episodes = int(run_param(context.params, "policy_selection_episodes"))
    if not episodes:
        return last, "the last update's policy was kept: policy_selection_episodes is 0"
    if on_arm:
        return last, "the last update's policy was kept: a real arm has no validation episodes to spare"

    def on_scored(fraction: float, score: PolicyScore) -> bool:
        done = ppo_share + (1 - ppo_share) * fraction
        return progress.update(done, {"policy_selection": asdict(score)})

    selection = select_policy(
        context.data, context.folder / "policy", context.candidate_var(), context.world, context.room,
        context.params["seed"], episodes, EVAL_NUM_ENVS, on_scored,
    )  # fmt: skip
    if isinstance(selection, str):
        return last, selection
    return Path(selection.chosen.checkpoint), selection.to_dict()


def evaluate(context: RunContext, progress: Progress) -> dict[str, Any]:
    """The candidate (this run's, or for an evaluate run the newest candidate version) against the parent;
    an evaluate run with no candidate scores the active version alone."""
    params = context.params
    per_intent = max(1, math.ceil(params["eval_episodes"] / 4))

    def score(var: Path, policy: Path | None) -> ModelScore:
        return score_model(
            context.data, var, policy, context.world, per_intent, context.room, params["seed"] + 7919,
            EVAL_NUM_ENVS,
        )  # fmt: skip

    if context.kind == models.RunKind.EVALUATE:
        if context.candidate_id is None:
            active = score(context.parent_var, context.parent_policy)
            progress.update(1.0, {"evaluation": active.to_dict()})
            return {"candidate": None, "active": active.to_dict()}
        candidate_var, candidate_policy = _candidate_version_files(context, context.candidate_id)
    else:
        candidate_var, candidate_policy = context.candidate_var(), context.candidate_policy()
    candidate = score(candidate_var, candidate_policy)
    if progress.update(0.5, {"candidate": candidate.to_dict()}):
        raise Cancelled("cancel requested during the evaluation")
    active = score(context.parent_var, context.parent_policy)
    progress.update(1.0, {"active": active.to_dict()})
    return {"candidate": candidate.to_dict(), "active": active.to_dict()}


STAGES: dict[str, Callable[[RunContext, Progress], dict[str, Any]]] = {
    "var_finetune": var_finetune,
    "policy_improve": policy_improve,
    "evaluate": evaluate,
}


def _live_rollouts(context: RunContext, stage: str, on_arm: str | None = None) -> Any:
    """The scene's live view of env 0 (`worker.live`) as a context manager; it gives None (no hook) when
    VARBOT_LIVE_ROLLOUT_HZ is 0, or on a real arm (the scene mirrors simulated worlds only)."""
    from worker.live import ROLLOUT_HZ, RolloutPublisher
    from worker.policy_stage import goal_clip_ids

    if ROLLOUT_HZ <= 0 or on_arm is not None:
        return contextlib.nullcontext()
    return RolloutPublisher(
        context.household_id, context.run_id, context.robot_id, context.world, stage,
        goal_clip_ids(context.data),
    )  # fmt: skip


def _candidate_version_files(context: RunContext, version_id: int) -> tuple[Path, Path | None]:
    blobs = get_blob_store()
    with get_session_factory()() as session:
        version = session.get_one(models.ModelVersion, version_id)
        folder = context.folder / f"candidate-{version.id}"
        return (
            materialise(blobs, version.var_key, folder / "var.pt"),
            materialise_optional(blobs, version.policy_key, folder / "policy.pt"),
        )


def _compact_policy(checkpoint: Path, out: Path) -> None:
    """The policy without optimiser and RNG state: what a model version needs to act and to improve."""
    from learning.rl.checkpoints import compact_policy_checkpoint

    compact_policy_checkpoint(checkpoint, out)
