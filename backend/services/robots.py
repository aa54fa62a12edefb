"""Robots of a household."""

from typing import Any

from sqlalchemy import exists, select
from sqlalchemy.orm import Session

from backend import models
from backend.errors import Conflict, Invalid, NotFound
from backend.schemas import RobotCreate, RobotPublic, RobotUpdate
from core.rooms import room_of


def get_robot(session: Session, household_id: int, robot_id: int) -> models.Robot:
    robot = session.get(models.Robot, robot_id)
    if robot is None or robot.household_id != household_id:
        raise NotFound("robot", robot_id)
    return robot


def active_model_ids(session: Session, household_id: int) -> dict[int, int]:
    rows = session.execute(
        select(models.ModelVersion.robot_id, models.ModelVersion.id).where(
            models.ModelVersion.household_id == household_id,
            models.ModelVersion.status == models.ModelStatus.ACTIVE,
        )
    )
    return {robot_id: version_id for robot_id, version_id in rows}


def public(robot: models.Robot, active: dict[int, int]) -> RobotPublic:
    return RobotPublic.model_validate(robot).model_copy(update={"active_model_id": active.get(robot.id)})


def list_robots(session: Session, household_id: int) -> list[models.Robot]:
    query = select(models.Robot).where(models.Robot.household_id == household_id).order_by(models.Robot.id)
    return list(session.scalars(query))


def create_robot(session: Session, household_id: int, body: RobotCreate) -> models.Robot:
    robot = models.Robot(
        household_id=household_id, name=body.name, kind=body.kind, settings=_checked(body.settings)
    )
    session.add(robot)
    session.commit()
    return robot


def update_robot(session: Session, robot: models.Robot, body: RobotUpdate) -> models.Robot:
    if body.name is not None:
        robot.name = body.name
    if body.settings is not None:
        robot.settings = _checked(body.settings)
    session.commit()
    return robot


def _checked(settings: dict[str, Any]) -> dict[str, Any]:
    """Settings whose room (`core.rooms`) the worker will be able to build."""
    try:
        room_of(settings)
    except ValueError as error:
        raise Invalid(str(error)) from None
    return settings


def delete_robot(session: Session, robot: models.Robot) -> None:
    for table, what in (
        (models.Snapshot, "snapshots"),
        (models.Run, "runs"),
        (models.ModelVersion, "model versions"),
    ):
        if session.scalar(select(exists().where(table.robot_id == robot.id))):
            raise Conflict(f"robot {robot.id} still has {what}; a robot with history cannot be deleted")
    session.delete(robot)
    session.commit()
