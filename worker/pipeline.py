"""One training run from start to end, safe to run twice and to resume after a crash.

- The QUEUED→RUNNING transition is one conditional UPDATE: only one delivery ever starts a run; a later
  delivery of a RUNNING run resumes it (after a killed worker), one of an ended run does nothing.
- A Redis lease (`worker.lease`) makes sure only one live worker works on a run at a time.
- Every stage (`worker.stages`) writes checkpoints into the run's folder (`data_dir()/runs/<id>/`) and, when
  done, its result into `state.json` (`worker.run_context`); a resumed run skips finished stages and
  continues the current one from its checkpoint.
- A run ends once, in one commit (`_end`): succeeded, failed or cancelled. A succeeded run's model version is
  created and promoted (or not) in that commit (`worker.promotion`), and `model_versions.run_id` is unique:
  one run gives exactly one version.
"""

import json
import logging
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import update

from backend import models
from backend.blobs import BlobStore
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services import model_versions
from backend.services.runs import publish_run
from worker.household import TooFewTriplets
from worker.lease import LEASE_S, RunLease
from worker.progress import STAGE_WEIGHTS, Cancelled, Progress, finite
from worker.promotion import Conclusion, conclude
from worker.run_context import RunContext, RunState, prepare_context, run_folder
from worker.stages import STAGES
from worker.var_stage import Diverged

logger = logging.getLogger(__name__)


def torch_threads() -> int:
    """One thread on a small shared machine (many tiny ops lose to OpenMP barriers), half the cores above."""
    configured = os.environ.get("VARBOT_TORCH_THREADS")
    if configured:
        return max(1, int(configured))
    cores = os.cpu_count() or 1
    return 1 if cores <= 4 else cores // 2


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
    failed = models.RunStatus.FAILED
    try:
        progress.check_cancel()
        context = prepare_context(run_id, kind, params, state, folder)
        _run_stages(context, state, progress)
        progress.enter("promoting")
        return _end(run_id, progress, folder, models.RunStatus.SUCCEEDED, finish=(context, state))
    except Cancelled as stop:
        _end(run_id, progress, folder, models.RunStatus.CANCELLED)
        return f"cancelled ({stop})"
    except TooFewTriplets as refusal:
        _end(run_id, progress, folder, failed, error=f"refused: {refusal}")
        return "refused: too few triplets"
    except Diverged as diverged:
        _end(run_id, progress, folder, failed, error=f"{progress.stage}: diverged: {diverged}")
        return "failed: diverged"
    except SoftTimeLimitExceeded:
        _end(run_id, progress, folder, failed, error=f"{progress.stage}: the run hit its time limit")
        return "failed: time limit"
    except Exception as error:
        logger.exception("run %s failed in %s", run_id, progress.stage)
        reason = f"{progress.stage}: {type(error).__name__}: {error}"
        _end(run_id, progress, folder, failed, error=reason[:2000])
        return f"failed: {reason[:200]}"


def _run_stages(context: RunContext, state: RunState, progress: Progress) -> None:
    """Every stage of the run's kind that has not finished yet, each result saved as soon as it is done."""
    for stage, _weight in STAGE_WEIGHTS[context.kind]:
        if stage in state.completed:
            continue
        progress.enter(stage)
        result = STAGES[stage](context, progress)
        result["seconds"] = progress.finish_stage()
        result["curve"] = progress.curves.get(stage, [])
        state.completed[stage] = result
        state.save()


def _end(
    run_id: int,
    progress: Progress,
    folder: Path,
    status: models.RunStatus,
    error: str | None = None,
    finish: tuple[RunContext, RunState] | None = None,
) -> str:
    """The run's one ending: its artifacts, metrics and timings, and (with `finish`, for a succeeded run) its
    conclusion, in one commit; a run that ended meanwhile (cancelled from outside) is left as it is."""
    artifacts = _store_artifacts(get_blob_store(), folder)
    succeeded = status == models.RunStatus.SUCCEEDED
    with get_session_factory()() as session:
        run = session.get_one(models.Run, run_id)
        if models.RunStatus(run.status).finished:
            return f"ended meanwhile ({run.status})"
        conclusion = conclude(session, run, *finish) if finish else Conclusion({}, status.value)
        run.metrics = _json_safe(
            {
                **(run.metrics or {}),
                "latest": progress.latest,
                "curves": progress.curves,
                "artifacts": artifacts,
                **conclusion.metrics,
            }
        )
        run.checkpoints = sorted(set(run.checkpoints or []) | set(artifacts.values()))
        run.timings = {
            **(run.timings or {}),
            "stages_s": progress.stage_seconds,
            "eta_s": 0.0 if succeeded else None,
        }
        run.status, run.error, run.finished_at = status, error, datetime.now(UTC)
        if succeeded:
            run.stage, run.progress = "done", 1.0
        else:
            run.stage = progress.stage if progress.stage != "starting" else status.value
        if conclusion.promoted is not None:
            model_versions.activate(session, conclusion.promoted)  # commits all
        else:
            session.commit()
        publish_run(run)
    return conclusion.outcome


def _store_artifacts(blobs: BlobStore, folder: Path) -> dict[str, str]:
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


def _json_safe(value: Any) -> Any:
    return json.loads(json.dumps(finite(value), default=str))
