from fastapi import APIRouter, status

from backend import schemas
from backend.api.responses import errors
from backend.deps import AdminDep, CallerDep, SessionDep
from backend.schemas import PathId
from backend.services import robots

router = APIRouter(prefix="/robots", tags=["robots"])


@router.get("", response_model=list[schemas.RobotPublic])
def list_robots(caller: CallerDep, session: SessionDep) -> list[schemas.RobotPublic]:
    active = robots.active_model_ids(session, caller.household_id)
    return [robots.public(robot, active) for robot in robots.list_robots(session, caller.household_id)]


@router.post("", response_model=schemas.RobotPublic, status_code=status.HTTP_201_CREATED)
def create_robot(body: schemas.RobotCreate, caller: AdminDep, session: SessionDep) -> schemas.RobotPublic:
    return robots.public(robots.create_robot(session, caller.household_id, body), {})


@router.get("/{robot_id}", response_model=schemas.RobotPublic)
def get_robot(robot_id: PathId, caller: CallerDep, session: SessionDep) -> schemas.RobotPublic:
    robot = robots.get_robot(session, caller.household_id, robot_id)
    return robots.public(robot, robots.active_model_ids(session, caller.household_id))


@router.patch("/{robot_id}", response_model=schemas.RobotPublic)
def update_robot(
    robot_id: PathId, body: schemas.RobotUpdate, caller: AdminDep, session: SessionDep
) -> schemas.RobotPublic:
    robot = robots.update_robot(session, robots.get_robot(session, caller.household_id, robot_id), body)
    return robots.public(robot, robots.active_model_ids(session, caller.household_id))


@router.delete("/{robot_id}", status_code=status.HTTP_204_NO_CONTENT, responses=errors(409))
def delete_robot(robot_id: PathId, caller: AdminDep, session: SessionDep) -> None:
    robots.delete_robot(session, robots.get_robot(session, caller.household_id, robot_id))
