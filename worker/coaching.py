"""A coaching-by-voice session on the robot queue (`backend.services.coaching` says what a session is): the
robot's model (its active version, or the world's base model) improves by PPO on the coached command at a
person's pace (`learning.rl.coaching`), the scene shows each step (the household's rollout channel), each
frame is kept for the member's clips to find, and each clip the API passes on is the current sound S_t of
the frames it overlaps. A finished session stores the improved policy as a candidate version (an `evaluate`
run judges it); a cancelled or failed one stores nothing more: the answers its clips gave are already
labels."""

import logging
import secrets
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select

from backend import models
from backend.blobs import BlobStore
from backend.broker import COACHING_STAGE
from backend.db import get_session_factory
from backend.deps import get_blob_store
from backend.services import coaching, model_versions
from backend.services.attempts import household_commands
from core.robots import world_of_kind
from core.rooms import room_of
from worker.attempts import AttemptRefused, RobotModel, feature_kind, robot_model
from worker.capture import png
from worker.live import RolloutPublisher

logger = logging.getLogger(__name__)

STATUS_EVERY_S = 0.5


def coach(
    session_id: str, robot_id: int, household_id: int, command: str, seconds: int, steps_per_s: float
) -> dict[str, Any]:
    """Runs the session to its end, its cancel, or a refusal (saying what to do); the status says which."""
    status = coaching.read_status(session_id) or {"robot_id": robot_id, "household_id": household_id}
    report = _reporter(session_id, status)
    try:
        return _coach(session_id, robot_id, household_id, command, seconds, steps_per_s, report)
    except AttemptRefused as refusal:
        report("refused", str(refusal))
        return {"state": "refused", "message": str(refusal)}
    except Exception as error:
        report("failed", f"the session failed ({type(error).__name__}: {error}); your answers are kept")
        raise


def _coach(
    session_id: str,
    robot_id: int,
    household_id: int,
    command: str,
    seconds: int,
    steps_per_s: float,
    report: Callable[..., None],
) -> dict[str, Any]:
    import torch

    from learning.rl.coaching import CoachingSettings, CoachingStopped, LiveCoach, coaching_trainer
    from learning.rl.rewards import ClipBank
    from learning.var.checkpoint import front_end_of, load_var

    torch.set_num_threads(1)
    blobs = get_blob_store()
    with get_session_factory()() as session:
        robot = session.get(models.Robot, robot_id)
        if robot is None or robot.household_id != household_id:
            raise AttemptRefused(f"robot {robot_id} of household {household_id} does not exist")
        world = world_of_kind(robot.kind)
        coached = household_commands(session, household_id).get(command)
        if coached is None:
            raise AttemptRefused("the coached command has no recording left: record it on the Record page")
        model = robot_model(session, blobs, robot, world)
        room = room_of(robot.settings or {})
        reader = ClipReader(blobs, feature_kind(world), front_end_of(model.var_path))
        goals = ClipBank(reader.features(session, list(coached.clip_ids)), np.full(len(coached.clip_ids), -1))
    var = load_var(model.var_path).eval()
    live = LiveCoach(lambda: reader.spoken(session_id, var))
    settings = CoachingSettings(
        steps=int(seconds * steps_per_s), steps_per_s=steps_per_s, seed=secrets.randbits(31)
    )
    run_dir = Path(tempfile.mkdtemp(prefix=f"coaching-{session_id}-"))
    publisher = RolloutPublisher(
        household_id, 0, robot_id, world, COACHING_STAGE, coached.clip_ids, rate_hz=2 * steps_per_s
    )
    stop = lambda: coaching.stop_asked(session_id)  # noqa: E731
    try:
        with coaching_trainer(
            model.policy_path, model.var_path, goals, live, settings, run_dir, room, stop
        ) as trainer:
            watcher = FrameKeeper(session_id, trainer, publisher, report, coached.name, settings.steps)
            report("running", f"the robot is working on “{coached.name}”: hold Space and say it when it is "
                   "where it should be", step=0)  # fmt: skip
            try:
                trainer.coach_session(watcher)
            except CoachingStopped:
                report("cancelled", f"stopped after {trainer.global_step} steps; your answers are kept")
                return {"state": "cancelled", "steps": trainer.global_step}
            version_id = _store_version(robot_id, model, trainer, coached.name, blobs)
    finally:
        publisher.close()
    report(
        "done", f"done: {trainer.voiced_steps} steps heard your voice; the coached robot is saved as "
        f"version {version_id}; on the Admin page, “Test the version in use” tests it against the one in use "
        "and keeps it only if it is better",
        step=trainer.global_step, voiced_steps=trainer.voiced_steps,
    )  # fmt: skip
    return {"state": "done", "steps": trainer.global_step, "version_id": version_id}


class ClipReader:
    """The household's clips as the VAR's sound front end reads them."""

    def __init__(self, blobs: BlobStore, kind: str, front_end: str) -> None:
        self.blobs, self.kind, self.front_end = blobs, kind, front_end
        self.seen = 0

    def features(self, session: Any, clip_ids: list[int]) -> np.ndarray:
        from learning.audio import features_from_bytes

        rows = {c.id: c for c in session.scalars(select(models.Clip).where(models.Clip.id.in_(clip_ids)))}
        return np.stack(
            [
                features_from_bytes(self.blobs.get(rows[i].wav_key), self.kind, self.front_end)
                for i in clip_ids
            ]
        ).astype(np.float32)

    def spoken(self, session_id: str, var: Any) -> list[Any]:
        """The clips the API passed on since the last call, embedded (`learning.rl.coaching.SpokenClip`)."""
        from learning.rl.coaching import SpokenClip, embed_clip_features

        new = coaching.clips_since(session_id, self.seen)
        self.seen += len(new)
        if not new:
            return []
        with get_session_factory()() as session:
            features = self.features(session, [int(item["clip_id"]) for item in new])
        return [
            SpokenClip(float(item["said_from"]), float(item["said_to"]), embed_clip_features(var, row))
            for item, row in zip(new, features, strict=True)
        ]


class FrameKeeper:
    """The watcher of each paced step: the scene's live view, the frame kept for clips, the status."""

    def __init__(
        self,
        session_id: str,
        trainer: Any,
        publisher: RolloutPublisher,
        report: Callable[..., None],
        command_name: str,
        steps: int,
    ) -> None:
        self.session_id, self.trainer, self.publisher, self.report = session_id, trainer, publisher, report
        self.command_name, self.steps = command_name, steps
        self.next_status_at = 0.0

    def __call__(self, step: Any) -> None:
        moment = self.trainer.moments[-1]
        frame = coaching.Frame(
            int(step.global_step), moment.shown_from, moment.shown_to, png(step.image),
            [float(v) for v in self.trainer.next_state[0].tolist()], int(self.trainer.heard[0]),
        )  # fmt: skip
        try:
            coaching.add_frame(self.session_id, frame)
        except Exception as error:  # a frame missed costs one view, never the session
            logger.warning("coaching frame %s not kept: %r", step.global_step, error)
        self.publisher(step)
        if time.monotonic() >= self.next_status_at:
            self.next_status_at = time.monotonic() + STATUS_EVERY_S
            self.report(
                "running", f"step {step.global_step} of {self.steps}: hold Space and say "
                f"“{self.command_name}” when the robot is where it should be",
                step=int(step.global_step), voiced_steps=self.trainer.voiced_steps,
            )  # fmt: skip


def _reporter(session_id: str, status: dict[str, Any]) -> Callable[..., None]:
    def report(state: str, message: str, **fields: Any) -> None:
        status.update(state=state, message=message, **fields)
        try:
            coaching.write_status(session_id, status)
        except Exception as error:  # best effort: the labels are the truth
            logger.warning("coaching status not written: %r", error)

    return report


def _store_version(robot_id: int, model: RobotModel, trainer: Any, command: str, blobs: BlobStore) -> int:
    """The coached policy as a candidate beside the model it started from (same VAR)."""
    from learning.rl.checkpoints import compact_policy_checkpoint

    trainer.save_checkpoint()
    compact = compact_policy_checkpoint(trainer.checkpoint_path, trainer.run_dir / "policy.pt")
    with get_session_factory()() as session:
        robot = session.get_one(models.Robot, robot_id)
        parent = session.get(models.ModelVersion, model.version_id) if model.version_id else None
        var_key = parent.var_key if parent is not None else blobs.put(model.var_path.read_bytes())
        version = model_versions.create_version(
            session, robot, var_key=var_key, policy_key=blobs.put(compact.read_bytes()),
            parent_id=model.version_id,
            metrics={"coaching": {"steps": trainer.global_step, "voiced_steps": trainer.voiced_steps}},
            notes=f"coached by voice on “{command}”: {trainer.voiced_steps} of {trainer.global_step} "
            "steps heard a voice",
        )  # fmt: skip
        session.commit()
        return int(version.id)
