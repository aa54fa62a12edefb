"""Asking the robot worker to adapt a robot's model to its room (`worker.room_adaptation`), and where such a
request stands (kept in Redis, as an attempts task's is)."""

from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend import broker, models
from backend.errors import Conflict, Unavailable
from backend.services.task_status import read_status, write_status
from core.rooms import MIN_ROOM_VIEWS


def live_views(session: Session, robot: models.Robot) -> int:
    return (
        session.scalar(
            select(func.count())
            .select_from(models.Snapshot)
            .where(models.Snapshot.robot_id == robot.id, models.Snapshot.deleted_at.is_(None))
        )
        or 0
    )


def ask_to_adapt(
    session: Session, robot: models.Robot, views: int, share: float, task_id: str, seed: int | None = None
) -> int:
    """Queue the adaptation to `views` views of the robot's room; how many it will use. A simulated robot's
    are rendered by the robot worker (from `seed`'s random moves, a fresh one when None); a real one's are
    its newest stored views, and a real robot with too few is refused at once, saying how many more to
    capture (share 0 needs none)."""
    if models.RobotKind(robot.kind).simulated or share == 0:
        queue_adaptation(robot, views, share, task_id, seed)
        return views if share > 0 else 0  # a simulated robot's views are rendered for it
    have = live_views(session, robot)
    if have < MIN_ROOM_VIEWS:
        raise Conflict(
            f"robot {robot.id} has {have} camera views and adapting to its room needs at least "
            f"{MIN_ROOM_VIEWS}: send {MIN_ROOM_VIEWS - have} more of its camera frames first (POST "
            "…/snapshots, or …/snapshots:capture for an arm the robot worker drives)"
        )
    queue_adaptation(robot, views, share, task_id, seed)
    return min(have, views)


def queue_adaptation(
    robot: models.Robot, views: int, share: float, task_id: str, seed: int | None = None
) -> None:
    kwargs = {
        "robot_id": robot.id, "household_id": robot.household_id, "views": views, "share": share, "seed": seed
    }  # fmt: skip
    try:
        write_status(broker.adaptation_status_key(task_id), queued(robot))
        broker.send_task(broker.TASK_ADAPT_TO_ROOM, kwargs, broker.QUEUE_ROBOT, task_id)
    except broker.BrokerUnavailable as exc:
        raise Unavailable(f"{exc}; the model was not changed") from exc


def queued(robot: models.Robot) -> dict[str, Any]:
    return {"state": "queued", "robot_id": robot.id, "message": "waiting for the robot worker"}


def adaptation_status(task_id: str) -> dict[str, Any] | None:
    return read_status(broker.adaptation_status_key(task_id))
