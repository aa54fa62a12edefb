"""Training runs: parameters from presets, enqueued by Celery task name, cancelled through a flag."""

import math
import uuid
from datetime import UTC, datetime
from typing import Any

from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import broker, models
from backend.errors import Conflict, Invalid, NotFound, Unavailable
from backend.schemas import PresetPublic, RunCreate, RunParams, RunPublic
from backend.services.robots import get_robot
from backend.services.triplets import triplet_stats
from core.robots import runs_on_robot_worker

PRESETS: dict[str, dict[str, Any]] = {
    "quick": dict(
        var_epochs=5,
        var_learning_rate=1e-4,
        var_batch_size=64,
        policy_steps=2_000,
        eval_episodes=20,
        held_out_fraction=0.2,
        seed=0,
    ),
    "standard": dict(
        var_epochs=20,
        var_learning_rate=1e-4,
        var_batch_size=128,
        policy_steps=20_000,
        eval_episodes=100,
        held_out_fraction=0.2,
        seed=0,
    ),
    "thorough": dict(
        var_epochs=40,
        var_learning_rate=1e-4,
        var_batch_size=128,
        policy_steps=100_000,
        eval_episodes=200,
        held_out_fraction=0.2,
        seed=0,
        policy_selection_episodes=40,
        # four standard households in unseen_room: 78.0 +- 3.3 % after, the training room -1.8 +- 3.5 points
        # with it; three without it 65.2 +- 5.0 % and -6.8 +- 11.1 (README, *Keeping the hidden layer ...*)
        var_keep_view=1.0,
    ),
}
# What a fine-tune's parts cost on this machine (2 CPU cores, 4,034 household triplets from about 760
# answers, the speech-embedding Kuka base), from the standard preset's run by bench/household.py
# (bench/results/household_4000_triplets.json, stages_s, load 0.8 -> 2.8): 55.51 s for 20 VAR epochs,
# 67.96 s for 20,000 policy steps, 61.96 s for 100 test episodes of each model. Each stage
# also starts workers and loads models once, which these per-unit costs spread over its units, so they
# over-predict a longer run: the thorough preset's run (bench/results/household_thorough.json) took
# 8.8 min where they predict 9.6 min. A VAR epoch's cost grows with the triplets it trains on: the thorough
# preset's runs from 1,001 to 1,096 triplets (bench/results/household_shipped_varview_*.json) took 6.7 to
# 8.9 min where these costs, scaled to their triplets, predict 8.4 to 8.5 min.
SECONDS_PER_VAR_EPOCH = 55.51 / 20
MEASURED_TRIPLETS = 4034  # that run's household triplets
MEASURED_REPLAY_FRACTION = 0.25  # that run's replay: an epoch's cost grows with its replayed triplets
SECONDS_PER_POLICY_STEP = 67.96 / 20_000
SECONDS_PER_TEST_EPISODE = 61.96 / 100
# the shipped bases' PPO (8 environments x 100 steps an update) keeps a numbered checkpoint every 25 updates
STEPS_PER_NUMBERED_CHECKPOINT = 8 * 100 * 25
# Choosing among them (bench/results/household_selected_unseen_room_seed{1,3}.json, load 0.8-4.7): the policy
# stage took 581 and 575 s where 100,000 steps alone took 297-318 s in the households before them, so about
# 270 s for 480 validation episodes in 12 batches of 40, each batch starting its own environments.
SECONDS_PER_VALIDATION_EPISODE = 270 / 480
BUDGET_MEASURED_BY = "bench/results/household_4000_triplets.json"
NEEDS_TRIPLETS = (models.RunKind.FINETUNE, models.RunKind.VAR_FINETUNE)
UNFINISHED = (models.RunStatus.QUEUED, models.RunStatus.RUNNING)


def resolve_params(preset: str, overrides: dict[str, Any]) -> RunParams:
    try:
        return RunParams(**(PRESETS[preset] | overrides))
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'params'}: {e['msg']}" for e in exc.errors())
        raise Invalid(f"invalid run parameters: {problems}") from exc


def seconds_per_var_epoch(replay_fraction: float, triplets: int = MEASURED_TRIPLETS) -> float:
    """A VAR epoch costs in proportion to its training triplets: the household's `triplets` plus the
    replayed ones, 1 / (1 - replay_fraction) times the household's in all."""
    measured_training_triplets = MEASURED_TRIPLETS / (1 - MEASURED_REPLAY_FRACTION)
    return SECONDS_PER_VAR_EPOCH * triplets / (1 - replay_fraction) / measured_training_triplets


def selection_episodes(params: RunParams) -> int:
    """The validation episodes of choosing among the policy's checkpoints (`worker.policy_selection`): the
    start, every numbered checkpoint and the last one, each in the robot's room and the training room."""
    if not params.policy_selection_episodes:
        return 0
    policies = 1 + math.ceil(params.policy_steps / STEPS_PER_NUMBERED_CHECKPOINT)
    return policies * 2 * params.policy_selection_episodes


def minutes_here(params: RunParams, triplets: int = MEASURED_TRIPLETS) -> float:
    """About how long a fine-tune with `params` takes on this machine with the household's `triplets`: VAR
    epochs, policy steps, validation and test episodes at the costs measured above."""
    seconds = (
        params.var_epochs * seconds_per_var_epoch(params.replay_fraction, triplets)
        + params.policy_steps * SECONDS_PER_POLICY_STEP
        + params.eval_episodes * SECONDS_PER_TEST_EPISODE
        + selection_episodes(params) * SECONDS_PER_VALIDATION_EPISODE
    )
    return round(seconds / 60, 1)


def published_presets(triplets: int | None = None) -> dict[str, PresetPublic]:
    """The presets with their budgets for a household with `triplets` (default: as many as the run the
    costs were measured on)."""
    budget_triplets = MEASURED_TRIPLETS if triplets is None else triplets
    return {
        name: PresetPublic(
            **params,
            minutes_here=minutes_here(RunParams(**params), budget_triplets),
            budget_triplets=budget_triplets,
            measured_by=BUDGET_MEASURED_BY,
        )
        for name, params in PRESETS.items()
    }


def get_run(session: Session, household_id: int, run_id: int) -> models.Run:
    run = session.get(models.Run, run_id)
    if run is None or run.household_id != household_id:
        raise NotFound("run", run_id)
    return run


def list_runs(
    session: Session, household_id: int, robot_id: int | None, status: str | None, limit: int, offset: int
) -> list[models.Run]:
    query = select(models.Run).where(models.Run.household_id == household_id)
    if robot_id is not None:
        query = query.where(models.Run.robot_id == robot_id)
    if status is not None:
        query = query.where(models.Run.status == status)
    return list(session.scalars(query.order_by(models.Run.id.desc()).limit(limit).offset(offset)))


def publish_run(run: models.Run) -> None:
    """Tell live streams about a run's new state (the workers call this after each throttled update)."""
    payload = {"type": "run", "run": RunPublic.model_validate(run).model_dump(mode="json")}
    broker.publish(broker.run_channel(run.household_id), payload)


def run_queue(robot_kind: str) -> str:
    """The queue a run of a `robot_kind` robot goes to (core.robots.runs_on_robot_worker)."""
    return broker.QUEUE_ROBOT if runs_on_robot_worker(robot_kind) else broker.QUEUE_TRAINING


def create_run(session: Session, requester: models.User, body: RunCreate, min_triplets: int) -> models.Run:
    robot = get_robot(session, requester.household_id, body.robot_id)
    params = resolve_params(body.preset, body.params)
    busy = session.scalar(
        select(models.Run.id).where(models.Run.robot_id == robot.id, models.Run.status.in_(UNFINISHED))
    )
    if busy is not None:
        raise Conflict(
            f"run {busy} is still queued or running for this robot; cancel it or wait for it to finish"
        )
    if body.kind in NEEDS_TRIPLETS:
        have = triplet_stats(session, requester.household_id, robot.id).triplets
        if have < min_triplets:
            raise Conflict(
                f"fine-tuning needs at least {min_triplets} triplets from this robot's labels and there "
                f"are {have}: answer more pairs on the Label page "
                "(each image needs one 'is' and one 'is not' answer)"
            )
    run = models.Run(
        household_id=requester.household_id,
        robot_id=robot.id,
        kind=body.kind,
        preset=body.preset,
        params=params.model_dump(),
        status=models.RunStatus.QUEUED,
        stage="queued",
        progress=0.0,
        requested_by_id=requester.id,
        task_id=uuid.uuid4().hex,
    )
    session.add(run)
    session.commit()
    try:
        broker.send_task(
            broker.RUN_TASKS[models.RunKind(run.kind)], {"run_id": run.id}, run_queue(robot.kind), run.task_id
        )
    except broker.BrokerUnavailable as exc:
        _finish(run, models.RunStatus.FAILED, error=f"could not be queued: {exc}")
        session.commit()
        publish_run(run)
        raise Unavailable(
            f"{exc}; the run was not started (is Redis running? see GET /api/v1/health)"
        ) from exc
    publish_run(run)
    return run


def cancel_run(session: Session, run: models.Run) -> models.Run:
    """Queued runs end at once; running ones get the flag and the worker stops at its next check."""
    if models.RunStatus(run.status).finished:
        raise Conflict(f"run {run.id} has already ended ({run.status})")
    run.cancel_requested = True
    if run.status == models.RunStatus.QUEUED:
        _finish(run, models.RunStatus.CANCELLED)
    session.commit()
    publish_run(run)
    return run


def _finish(run: models.Run, status: models.RunStatus, error: str | None = None) -> None:
    run.status = status
    run.stage = status.value
    run.error = error
    run.finished_at = datetime.now(UTC)
