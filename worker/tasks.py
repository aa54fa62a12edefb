"""The Celery tasks, named as `backend/broker.py` says. Each is a thin call into `worker.pipeline` /
`worker.capture`; torch and pybullet are imported inside them, never at worker start-up."""

import logging

from celery import Task

from backend import broker
from backend.models import RunKind
from worker.celery_app import (
    CAPTURE_HARD_LIMIT_S,
    CAPTURE_SOFT_LIMIT_S,
    TRAINING_HARD_LIMIT_S,
    TRAINING_SOFT_LIMIT_S,
    app,
)

logger = logging.getLogger(__name__)

_TRAINING = dict(
    bind=True,
    acks_late=True,
    reject_on_worker_lost=True,
    soft_time_limit=TRAINING_SOFT_LIMIT_S,
    time_limit=TRAINING_HARD_LIMIT_S,
    queue=broker.QUEUE_TRAINING,
)
_ROBOT = dict(
    bind=True,
    acks_late=True,
    reject_on_worker_lost=True,
    soft_time_limit=CAPTURE_SOFT_LIMIT_S,
    time_limit=CAPTURE_HARD_LIMIT_S,
    queue=broker.QUEUE_ROBOT,
)


def _run(task: Task, run_id: int) -> str:
    from worker.pipeline import execute_run

    outcome = execute_run(int(run_id))
    logger.info("%s: %s", task.name, outcome)
    return outcome


@app.task(name=broker.RUN_TASKS[RunKind.FINETUNE], **_TRAINING)
def finetune(self: Task, run_id: int) -> str:
    """VAR fine-tune → policy self-improvement → evaluation → promotion gate."""
    return _run(self, run_id)


@app.task(name=broker.RUN_TASKS[RunKind.VAR_FINETUNE], **_TRAINING)
def var_finetune(self: Task, run_id: int) -> str:
    """VAR fine-tune only (the parent's policy is kept) → evaluation → promotion gate."""
    return _run(self, run_id)


@app.task(name=broker.RUN_TASKS[RunKind.POLICY_IMPROVE], **_TRAINING)
def policy_improve(self: Task, run_id: int) -> str:
    """Policy self-improvement with the active VAR → evaluation → promotion gate."""
    return _run(self, run_id)


@app.task(name=broker.RUN_TASKS[RunKind.EVALUATE], **_TRAINING)
def evaluate(self: Task, run_id: int) -> str:
    """Score the newest candidate against the active version and apply the promotion gate (or, with no
    candidate, score the active version)."""
    return _run(self, run_id)


@app.task(name=broker.TASK_CAPTURE_SNAPSHOTS, **_ROBOT)
def capture_snapshots(self: Task, robot_id: int, household_id: int, count: int) -> dict:
    """Render `count` camera views from random poses of a simulated robot into snapshots (a real arm:
    its camera's views, `worker.real_arm`)."""
    from worker.capture import capture_views
    from worker.real_arm import capture_arm_views, is_real_arm

    capture = capture_arm_views if is_real_arm(robot_id) else capture_views
    result = capture(robot_id, household_id, count, task_id=self.request.id)
    logger.info("captured %s views for robot %s", result["created"], robot_id)
    return {k: v for k, v in result.items() if k != "snapshot_ids"}


@app.task(name=broker.TASK_ADAPT_TO_ROOM, **_ROBOT)
def adapt_to_room(
    self: Task, robot_id: int, household_id: int, views: int, share: float, seed: int | None = None
) -> dict:
    """The robot's model adapted to views of its room (`worker.room_adaptation`), made active; what cannot
    be adapted (a real robot with too few frames, no VAR) ends the task as refused, saying what to do."""
    from backend.services.task_status import write_status
    from worker.room_adaptation import AdaptationRefused, adapt_robot_to_room

    def report(state: str, message: str, version_id: int | None = None) -> None:
        status = {"state": state, "message": message, "version_id": version_id, "robot_id": robot_id}
        write_status(broker.adaptation_status_key(self.request.id), status)

    report("running", "adapting the model to the room's views")
    try:
        result = adapt_robot_to_room(robot_id, household_id, views, share, seed)
    except AdaptationRefused as refusal:
        report("refused", str(refusal))
        return {"robot_id": robot_id, "refused": str(refusal)}
    except Exception as error:
        report("failed", f"{type(error).__name__}: {error}; the active model was not changed")
        raise
    report("done", f"version {result['version_id']} is active: {result['notes']}", result["version_id"])
    logger.info("robot %s adapted to its room: version %s", robot_id, result["version_id"])
    return {k: v for k, v in result.items() if k not in ("mean_shift", "notes")}


@app.task(name=broker.TASK_TRY_COMMANDS, **_ROBOT)
def try_commands(
    self: Task,
    robot_id: int,
    household_id: int,
    attempts: int,
    random_views: int,
    commands: list[str],
    seed: int | None = None,
) -> dict:
    """The robot tries the household's recorded commands with its active policy (or its base model): each
    attempt's final view becomes a snapshot to judge, with its replay; then `random_views` random views.
    What cannot work (no model, no recordings) ends the task as refused, saying what to do."""
    from worker.attempts import AttemptRefused, report_refusal
    from worker.attempts import try_commands as try_in_world
    from worker.real_arm import is_real_arm, try_arm_commands

    attempt = try_arm_commands if is_real_arm(robot_id) else try_in_world
    try:
        result = attempt(
            robot_id, household_id, attempts, random_views, commands, task_id=self.request.id, seed=seed
        )
    except AttemptRefused as refusal:
        report_refusal(self.request.id, robot_id, "refused", str(refusal))
        logger.info("attempts for robot %s refused: %s", robot_id, refusal)
        return {"robot_id": robot_id, "refused": str(refusal)}
    except Exception as error:
        report_refusal(self.request.id, robot_id, "failed", f"{type(error).__name__}: {error}")
        raise
    logger.info("stored %s attempts for robot %s", result["created"], robot_id)
    return {k: v for k, v in result.items() if k != "snapshot_ids"}


@app.task(name=broker.TASK_COACH, **_ROBOT)
def coach(
    self: Task,
    session_id: str,
    robot_id: int,
    household_id: int,
    command: str,
    seconds: int,
    steps_per_s: float,
) -> dict:
    """A coaching-by-voice session (`worker.coaching`): the robot improves on one command at a person's pace
    while a member's clips are its current sound; a refusal or failure is said in the session's status."""
    from worker.coaching import coach as coach_session

    result = coach_session(session_id, robot_id, household_id, command, seconds, steps_per_s)
    logger.info("coaching session %s: %s", session_id, result["state"])
    return result
