"""Run progress: stage, progress 0–1, latest metrics, curves and ETA on the run row, at a throttled rate,
published on the household's pub/sub channel after every write. Each write also reads the cancel flag."""

import math
import os
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from backend import models
from backend.db import get_session_factory
from backend.services.runs import publish_run

WRITE_INTERVAL_S = float(os.environ.get("VARBOT_PROGRESS_INTERVAL_S", 1.0))
MAX_CURVE_POINTS = 200

# Share of a run's progress bar taken by each stage, per run kind.
STAGE_WEIGHTS: dict[str, list[tuple[str, float]]] = {
    models.RunKind.FINETUNE: [("var_finetune", 0.3), ("policy_improve", 0.5), ("evaluate", 0.2)],
    models.RunKind.VAR_FINETUNE: [("var_finetune", 0.7), ("evaluate", 0.3)],
    models.RunKind.POLICY_IMPROVE: [("policy_improve", 0.75), ("evaluate", 0.25)],
    models.RunKind.EVALUATE: [("evaluate", 1.0)],
}


class Cancelled(Exception):
    """The run's cancel flag was set; the stage stopped after saving its checkpoint."""


def finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN; the database column is JSON
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


@dataclass
class Progress:
    run_id: int
    kind: str
    interval_s: float = WRITE_INTERVAL_S
    stage: str = "starting"
    fraction: float = 0.0
    cancel_requested: bool = False
    latest: dict[str, Any] = field(default_factory=dict)
    curves: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    stage_seconds: dict[str, float] = field(default_factory=dict)
    completed: set[str] = field(default_factory=set)
    _stage_started: float = field(default_factory=time.monotonic)
    _run_started: float = field(default_factory=time.monotonic)
    _last_write: float = 0.0

    @property
    def weights(self) -> list[tuple[str, float]]:
        return STAGE_WEIGHTS[self.kind]

    def overall(self) -> float:
        """The finished stages' weights plus the current stage's share; a stage outside the table (starting,
        promoting) adds nothing of its own."""
        done = sum(weight for name, weight in self.weights if name in self.completed)
        current = dict(self.weights).get(self.stage, 0.0) if self.stage not in self.completed else 0.0
        return min(1.0, done + current * min(max(self.fraction, 0.0), 1.0))

    def restore(self, completed: dict[str, Any]) -> None:
        """After a resume: stages finished before the crash count as done."""
        for name, result in completed.items():
            self.completed.add(name)
            self.stage_seconds[name] = float(result.get("seconds", 0.0))
            if result.get("curve"):
                self.curves[name] = result["curve"]

    def enter(self, stage: str) -> bool:
        self._close_stage()
        self.stage, self.fraction, self._stage_started = stage, 0.0, time.monotonic()
        return self.write(force=True)

    def _close_stage(self) -> None:
        now = time.monotonic()
        if self.stage in dict(self.weights):
            self.stage_seconds[self.stage] = round(
                self.stage_seconds.get(self.stage, 0.0) + now - self._stage_started, 2
            )
        self._stage_started = now

    def update(
        self, fraction: float, metrics: dict[str, Any] | None = None, point: dict[str, Any] | None = None
    ) -> bool:
        """Record progress within the stage; returns True when the run should stop (cancel requested)."""
        self.fraction = fraction
        if metrics:
            self.latest.update(metrics)
        if point:
            curve = self.curves.setdefault(self.stage, [])
            curve.append(point)
            if len(curve) > MAX_CURVE_POINTS:
                del curve[1::2]  # keep the shape, halve the resolution
        return self.write()

    def check_cancel(self) -> None:
        if self.write():
            raise Cancelled(f"cancel requested during {self.stage}")

    def write(self, force: bool = False) -> bool:
        now = time.monotonic()
        if not force and now - self._last_write < self.interval_s:
            return self.cancel_requested
        self._last_write = now
        overall = self.overall()
        elapsed = now - self._run_started
        eta = elapsed * (1 - overall) / overall if overall >= 0.02 else None
        with get_session_factory()() as session:
            run = session.get_one(models.Run, self.run_id)
            self.cancel_requested = bool(run.cancel_requested)
            if models.RunStatus(run.status).finished:
                return True
            run.stage = self.stage
            run.progress = max(run.progress or 0.0, round(overall, 4))
            run.metrics = finite({**(run.metrics or {}), "latest": dict(self.latest), "curves": self.curves})
            run.timings = finite(
                {
                    **(run.timings or {}),
                    "stages_s": {
                        **self.stage_seconds,
                        self.stage: round(
                            self.stage_seconds.get(self.stage, 0.0) + now - self._stage_started, 2
                        ),
                    },
                    "eta_s": None if eta is None else round(eta, 1),
                    "updated": datetime.now(UTC).isoformat(),
                }
            )
            session.commit()
            publish_run(run)
        return self.cancel_requested

    def finish_stage(self) -> float:
        """Close the current stage (it counts as done); returns its wall time in seconds."""
        self._close_stage()
        self.completed.add(self.stage)
        return self.stage_seconds.get(self.stage, 0.0)
