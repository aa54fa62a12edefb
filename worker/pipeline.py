"""One training run from start to end, safe to run twice and to resume after a crash.

- The QUEUED→RUNNING transition is one conditional UPDATE: only one delivery ever starts a run; a later
  delivery of a RUNNING run resumes it (after a killed worker), one of an ended run does nothing.
- A Redis lease (`worker.lease`) makes sure only one live worker works on a run at a time.
- Every stage writes checkpoints into the run's folder (`data_dir()/runs/<id>/`) and, when done, its result
  into `state.json`; a resumed run skips finished stages and continues the current one from its checkpoint.
- The model version is created and promoted (or not) in the same commit that marks the run SUCCEEDED, and
  `model_versions.run_id` is unique: one run gives exactly one version.
"""

import contextlib
import json
import logging
import math
import os
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import select, update

from backend import models
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services import model_versions
from backend.services.runs import publish_run
from backend.settings import get_settings
from core.paths import data_subdir
from core.robots import world_of_kind
from worker.base_models import BaseModelMissing, find_base
from worker.evaluation import ModelScore, decide, score_model, summarise_scores
from worker.household import HouseholdData, TooFewTriplets, load_household
from worker.lease import LEASE_S, RunLease
from worker.progress import STAGE_WEIGHTS, Cancelled, Progress, finite
from worker.var_stage import Diverged

logger = logging.getLogger(__name__)

STATE_FILE = "state.json"
EVAL_NUM_ENVS = int(os.environ.get("VARBOT_EVAL_NUM_ENVS", 4))


def run_folder(run_id: int) -> Path:
    return data_subdir("runs", str(run_id))


def torch_threads() -> int:
    """One thread on a small shared machine (many tiny ops lose to OpenMP barriers), half the cores above."""
    configured = os.environ.get("VARBOT_TORCH_THREADS")
    if configured:
        return max(1, int(configured))
    cores = os.cpu_count() or 1
    return 1 if cores <= 4 else cores // 2


# --- entry point ----------------------------------------------------------------------------------------


def execute_run(run_id: int) -> str:
    """Run (or resume) training run `run_id`; returns what happened, for the worker log."""
    lease = RunLease(run_id)
    if not lease.acquire(wait_s=LEASE_S * 2.5, still_wanted=lambda: not _ended(run_id)):
        return f"run {run_id}: another live worker holds it (or it ended); nothing to do"
    try:
        claim = _claim(run_id)
        if claim not in ("started", "resumed"):
            return f"run {run_id}: {claim}"
        return f"run {run_id} ({claim}): {_execute(run_id, resumed=claim == 'resumed')}"
    finally:
        lease.release()


def _ended(run_id: int) -> bool:
    with get_session_factory()() as session:
        run = session.get(models.Run, run_id)
        return run is None or models.RunStatus(run.status).finished


def _claim(run_id: int) -> str:
    now = datetime.now(UTC)
    with get_session_factory()() as session:
        taken = session.execute(
            update(models.Run)
            .where(models.Run.id == run_id, models.Run.status == models.RunStatus.QUEUED)
            .values(status=models.RunStatus.RUNNING, stage="starting", started_at=now, updated_at=now)
        ).rowcount
        session.commit()
        run = session.get(models.Run, run_id)
        if run is None:
            return "no such run"
        if taken == 1:
            publish_run(run)
            return "started"
        if run.status == models.RunStatus.RUNNING:
            return "resumed"
        return f"already {run.status}"


# --- the run --------------------------------------------------------------------------------------------


class RunState:
    """`state.json`: the parent version, and the result of every finished stage."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / STATE_FILE
        self.data: dict[str, Any] = (
            json.loads(self.path.read_text()) if self.path.is_file() else {"completed": {}}
        )

    @property
    def completed(self) -> dict[str, Any]:
        return self.data["completed"]

    def save(self) -> None:
        temporary = self.path.with_suffix(".tmp")
        temporary.write_text(json.dumps(self.data, indent=2, default=str))
        os.replace(temporary, self.path)


def _execute(run_id: int, resumed: bool) -> str:
    import torch

    torch.set_num_threads(torch_threads())
    folder = run_folder(run_id)
    state = RunState(folder)
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        kind, params = models.RunKind(run.kind), dict(run.params)
    progress = Progress(run_id, kind)
    progress.restore(state.completed)
    if resumed:
        progress.latest["resumed_at"] = datetime.now(UTC).isoformat()
    try:
        progress.check_cancel()
        context = _prepare(run_id, kind, params, state, folder)
        for stage, _weight in STAGE_WEIGHTS[kind]:
            if stage in state.completed:
                continue
            progress.enter(stage)
            result = STAGES[stage](context, progress)
            result["seconds"] = progress.finish_stage()
            result["curve"] = progress.curves.get(stage, [])
            state.completed[stage] = result
            state.save()
        progress.enter("promoting")
        return _finish_succeeded(run_id, context, state, progress)
    except Cancelled as stop:
        _end(run_id, models.RunStatus.CANCELLED, progress, None, folder)
        return f"cancelled ({stop})"
    except TooFewTriplets as refusal:
        _end(run_id, models.RunStatus.FAILED, progress, f"refused: {refusal}", folder)
        return "refused: too few triplets"
    except Diverged as diverged:
        _end(run_id, models.RunStatus.FAILED, progress, f"{progress.stage}: diverged: {diverged}", folder)
        return "failed: diverged"
    except SoftTimeLimitExceeded:
        _end(
            run_id, models.RunStatus.FAILED, progress, f"{progress.stage}: the run hit its time limit", folder
        )
        return "failed: time limit"
    except Exception as error:
        logger.exception("run %s failed in %s", run_id, progress.stage)
        reason = f"{progress.stage}: {type(error).__name__}: {error}"
        _end(run_id, models.RunStatus.FAILED, progress, reason[:2000], folder)
        return f"failed: {reason[:200]}"


class RunContext:
    """Everything the stages read: the household's data, the parent's weights, the run's parameters."""

    def __init__(self, **values: Any) -> None:
        self.__dict__.update(values)

    run_id: int
    kind: models.RunKind
    params: dict[str, Any]
    folder: Path
    world: str
    domain: Any
    robot_id: int
    household_id: int
    parent_id: int
    parent_var: Path
    parent_policy: Path | None
    data: HouseholdData
    candidate_id: int | None


def _prepare(
    run_id: int, kind: models.RunKind, params: dict[str, Any], state: RunState, folder: Path
) -> RunContext:
    from learning.var.checkpoint import read_checkpoint

    blobs = get_blob_store()
    settings = get_settings()
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        robot = session.get_one(models.Robot, run.robot_id)
        world = world_of_kind(robot.kind)
        if "parent_id" not in state.data:
            state.data["parent_id"] = _active_or_base(session, robot, world).id
            state.save()
        parent = session.get_one(models.ModelVersion, state.data["parent_id"])
        candidate_id = None
        if kind == models.RunKind.EVALUATE:
            candidate_id = session.scalar(
                select(models.ModelVersion.id)
                .where(
                    models.ModelVersion.robot_id == robot.id,
                    models.ModelVersion.status == models.ModelStatus.CANDIDATE,
                )
                .order_by(models.ModelVersion.id.desc())
            )
        parent_var = _materialise(blobs, parent.var_key, folder / "parent" / "var.pt")
        parent_policy = _materialise(blobs, parent.policy_key, folder / "parent" / "policy.pt")
        image_size = int(read_checkpoint(parent_var)["config"]["image_size"])
        try:
            feature_kind = find_base(world).feature_kind
        except BaseModelMissing:
            feature_kind = "speech"
        needs = settings.min_triplets_for_training if kind in _TRAINS_VAR else 2
        data = load_household(
            session,
            blobs,
            robot,
            image_size,
            feature_kind,
            params["held_out_fraction"],
            params["seed"],
            needs,
        )
        domain = _domain(robot.settings or {})
        robot_id, household_id = robot.id, robot.household_id
    return RunContext(
        run_id=run_id, kind=kind, params=params, folder=folder, world=world, domain=domain,
        robot_id=robot_id, household_id=household_id, parent_id=state.data["parent_id"],
        parent_var=parent_var, parent_policy=parent_policy, data=data, candidate_id=candidate_id,
    )  # fmt: skip


_TRAINS_VAR = (models.RunKind.FINETUNE, models.RunKind.VAR_FINETUNE)


def _domain(settings: dict[str, Any]) -> Any:
    """The robot's room, for simulated robots: `settings["domain"]` holds DomainShift fields."""
    shift = settings.get("domain")
    if not shift:
        return None
    from sim.domain import DomainShift

    if shift == "unseen_room":
        return DomainShift.unseen_room()
    return DomainShift(**{k: tuple(v) if isinstance(v, list) else v for k, v in shift.items()})


def _materialise(blobs: Any, key: str | None, path: Path) -> Path | None:
    if key is None:
        return None
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(".tmp")
        temporary.write_bytes(blobs.get(key))
        os.replace(temporary, path)
    return path


def _active_or_base(session: Any, robot: models.Robot, world: str) -> models.ModelVersion:
    """The robot's active version; a robot that never had one gets the shipped base model, made active."""
    active = model_versions.active_version(session, robot.id)
    if active is not None:
        return active
    base = find_base(world)
    blobs = get_blob_store()
    version = model_versions.create_version(
        session,
        robot,
        var_key=blobs.put(base.var_path.read_bytes()),
        policy_key=blobs.put(base.policy_path.read_bytes()),
        metrics={"base_model": base.record},
        notes=f"base model for the simulated {world} world ({base.folder})",
    )
    model_versions.activate(session, version)  # commits
    return version


# --- stages ---------------------------------------------------------------------------------------------


def _var_finetune(context: RunContext, progress: Progress) -> dict[str, Any]:
    from worker.var_stage import finetune_var

    params = context.params

    def on_epoch(fraction: float, record: dict[str, Any]) -> bool:
        return progress.update(fraction, {"var": record}, point=record)

    result = finetune_var(
        context.data,
        context.parent_var,
        context.folder / "var",
        epochs=params["var_epochs"],
        batch_size=params["var_batch_size"],
        learning_rate=params["var_learning_rate"],
        seed=params["seed"],
        on_epoch=on_epoch,
    )
    return {k: str(v) if isinstance(v, Path) else v for k, v in asdict(result).items()}


def _policy_improve(context: RunContext, progress: Progress) -> dict[str, Any]:
    from worker.policy_stage import improve_policy

    if context.parent_policy is None:
        raise ValueError(f"model version {context.parent_id} has no policy to improve")

    def on_update(fraction: float, point: dict[str, Any]) -> bool:
        for key, value in point.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise Diverged(f"{key} became {value} at PPO update {point['update']}")
        return progress.update(fraction, {"policy": point}, point=point)

    with _live_rollouts(context, "policy_improve") as live:
        result = improve_policy(
            context.data,
            context.parent_policy,
            _candidate_var(context),
            context.params["policy_steps"],
            context.folder / "policy",
            context.params["seed"],
            on_update,
            live,
        )
    compact = context.folder / "policy" / "final.pt"
    _compact_policy(result.checkpoint, compact)
    return {
        "checkpoint": str(compact),
        "env_steps": result.env_steps,
        "updates": result.updates,
        "recent_success": result.recent_success,
        "time_shares": result.summary.get("time_shares"),
    }


def _live_rollouts(context: RunContext, stage: str) -> Any:
    """The scene's live view of env 0 (`worker.live`) as a context manager; it gives None (no hook) when
    VARBOT_LIVE_ROLLOUT_HZ is 0."""
    from worker.live import ROLLOUT_HZ, RolloutPublisher
    from worker.policy_stage import goal_clip_ids

    if ROLLOUT_HZ <= 0:
        return contextlib.nullcontext()
    return RolloutPublisher(
        context.household_id, context.run_id, context.robot_id, context.world, stage,
        goal_clip_ids(context.data),
    )  # fmt: skip


def _evaluate(context: RunContext, progress: Progress) -> dict[str, Any]:
    params = context.params
    per_intent = max(1, math.ceil(params["eval_episodes"] / 4))

    def score(var: Path, policy: Path | None) -> ModelScore:
        return score_model(
            context.data, var, policy, context.world, per_intent, context.domain, params["seed"] + 7919,
            EVAL_NUM_ENVS,
        )  # fmt: skip

    if context.kind == models.RunKind.EVALUATE:
        if context.candidate_id is None:
            active = score(context.parent_var, context.parent_policy)
            progress.update(1.0, {"evaluation": active.to_dict()})
            return {"candidate": None, "active": active.to_dict()}
        candidate_var, candidate_policy = _candidate_files(context)
    else:
        candidate_var, candidate_policy = _candidate_var(context), _candidate_policy(context)
    candidate = score(candidate_var, candidate_policy)
    if progress.update(0.5, {"candidate": candidate.to_dict()}):
        raise Cancelled("cancel requested during the evaluation")
    active = score(context.parent_var, context.parent_policy)
    progress.update(1.0, {"active": active.to_dict()})
    return {"candidate": candidate.to_dict(), "active": active.to_dict()}


STAGES = {"var_finetune": _var_finetune, "policy_improve": _policy_improve, "evaluate": _evaluate}


def _candidate_var(context: RunContext) -> Path:
    done = _completed(context).get("var_finetune")
    return Path(done["checkpoint"]) if done else context.parent_var


def _candidate_policy(context: RunContext) -> Path | None:
    done = _completed(context).get("policy_improve")
    return Path(done["checkpoint"]) if done else context.parent_policy


def _completed(context: RunContext) -> dict[str, Any]:
    return RunState(context.folder).completed


def _candidate_files(context: RunContext) -> tuple[Path, Path | None]:
    blobs = get_blob_store()
    with get_session_factory()() as session:
        version = session.get_one(models.ModelVersion, context.candidate_id)
        folder = context.folder / f"candidate-{version.id}"
        return (
            _materialise(blobs, version.var_key, folder / "var.pt"),  # type: ignore[return-value]
            _materialise(blobs, version.policy_key, folder / "policy.pt"),
        )


def _compact_policy(checkpoint: Path, out: Path) -> None:
    """The policy without optimiser and RNG state: what a model version needs to act and to improve."""
    import torch

    from learning.rl.ppo import read_policy_checkpoint

    payload = read_policy_checkpoint(checkpoint)
    kept = {
        k: payload[k]
        for k in ("kind", "format_version", "config", "policy_config", "policy", "label_counts")
        if k in payload
    }
    torch.save(kept, out)


# --- ending ---------------------------------------------------------------------------------------------


def _finish_succeeded(run_id: int, context: RunContext, state: RunState, progress: Progress) -> str:
    blobs = get_blob_store()
    scores = state.completed["evaluate"]
    candidate = ModelScore(**scores["candidate"]) if scores["candidate"] else None
    active = ModelScore(**scores["active"]) if scores["active"] else None
    artifact_keys = _store_artifacts(blobs, context.folder)
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        if run.status != models.RunStatus.RUNNING:
            return f"ended meanwhile ({run.status})"
        robot = session.get_one(models.Robot, context.robot_id)
        metrics = {
            **(run.metrics or {}),
            "latest": progress.latest,
            "curves": progress.curves,
            "labels_used": context.data.labels_used,
            "triplets": {
                "train": len(context.data.train_triplets),
                "held_out": len(context.data.test_triplets),
            },
            "stages": {
                k: {kk: vv for kk, vv in v.items() if kk != "curve"} for k, v in state.completed.items()
            },
            "artifacts": artifact_keys,
        }
        outcome = "evaluated"
        if candidate is None:
            metrics["evaluation"] = {"active": active.to_dict() if active else None}
        else:
            decision = decide(candidate, active)
            metrics["evaluation"] = summarise_scores(candidate, active)
            metrics["gate"] = {"promoted": decision.promote, "reasons": decision.reasons}
            version = _candidate_version(session, blobs, robot, context, run, metrics)
            version.metrics = {
                **(version.metrics or {}),
                "evaluation": metrics["evaluation"],
                "gate": metrics["gate"],
            }
            version.notes = ("promoted: " if decision.promote else "kept as candidate: ") + "; ".join(
                decision.reasons
            )
            metrics["model_version_id"] = version.id
            outcome = f"version {version.id} {'promoted' if decision.promote else 'kept as candidate'}"
        run.metrics = _json_safe(metrics)
        run.checkpoints = sorted(set(run.checkpoints or []) | set(artifact_keys.values()))
        run.timings = {**(run.timings or {}), "stages_s": progress.stage_seconds, "eta_s": 0.0}
        run.status, run.stage, run.progress = models.RunStatus.SUCCEEDED, "done", 1.0
        run.finished_at = datetime.now(UTC)
        promote_id = metrics.get("model_version_id") if metrics.get("gate", {}).get("promoted") else None
        if promote_id is not None:
            model_versions.activate(session, session.get_one(models.ModelVersion, promote_id))  # commits all
        else:
            session.commit()
        publish_run(run)
    return outcome


def _candidate_version(
    session: Any, blobs: Any, robot: models.Robot, context: RunContext, run: models.Run, metrics: dict
) -> models.ModelVersion:
    """The run's version: the one an earlier, interrupted finish already created, or a new candidate."""
    if context.kind == models.RunKind.EVALUATE:
        return session.get_one(models.ModelVersion, context.candidate_id)
    existing = session.scalar(select(models.ModelVersion).where(models.ModelVersion.run_id == run.id))
    if existing is not None:
        return existing
    var_path, policy_path = _candidate_var(context), _candidate_policy(context)
    return model_versions.create_version(
        session,
        robot,
        var_key=blobs.put(var_path.read_bytes()),
        policy_key=blobs.put(policy_path.read_bytes()) if policy_path else None,
        parent_id=context.parent_id,
        run_id=run.id,
        metrics={"labels_used": metrics["labels_used"], "triplets": metrics["triplets"]},
    )


def _store_artifacts(blobs: Any, folder: Path) -> dict[str, str]:
    """Checkpoints and training curves of the run, in the blob store (kept after failures too)."""
    candidates = {
        "var_checkpoint": folder / "var" / "last.pt",
        "var_final": folder / "var" / "final.pt",
        "policy_checkpoint": folder / "policy" / "checkpoint.pt",
        "policy_final": folder / "policy" / "final.pt",
        "policy_metrics": folder / "policy" / "metrics.jsonl",
        "policy_curves_png": folder / "policy" / "curves.png",
    }
    return {name: blobs.put(path.read_bytes()) for name, path in candidates.items() if path.is_file()}


def _end(run_id: int, status: models.RunStatus, progress: Progress, error: str | None, folder: Path) -> None:
    keys = _store_artifacts(get_blob_store(), folder)
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        if models.RunStatus(run.status).finished:
            return
        run.status = status
        run.stage = progress.stage if progress.stage != "starting" else status.value
        run.error = error
        run.finished_at = datetime.now(UTC)
        run.metrics = _json_safe(
            {**(run.metrics or {}), "latest": progress.latest, "curves": progress.curves, "artifacts": keys}
        )
        run.checkpoints = sorted(set(run.checkpoints or []) | set(keys.values()))
        run.timings = {**(run.timings or {}), "stages_s": progress.stage_seconds, "eta_s": None}
        session.commit()
        publish_run(run)


def _json_safe(value: Any) -> Any:
    return json.loads(json.dumps(finite(value), default=str))


def wait_for_run(run_id: int, timeout_s: float) -> models.Run:
    """For tools and tests: poll until the run ends."""
    deadline = time.monotonic() + timeout_s
    while True:
        with get_session_factory()() as session:
            run = session.get_one(models.Run, run_id)
            if models.RunStatus(run.status).finished or time.monotonic() > deadline:
                return run
        time.sleep(0.5)
