"""The robot's attempts at the household's commands, and the "did it do what I said?" labelling mode
(`backend.services.attempts`)."""

import uuid
from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query, Request, Response, status
from pydantic import BaseModel, Field, StringConstraints

from backend import broker, schemas
from backend.api.ranges import ranged_response
from backend.api.responses import errors
from backend.deps import BlobsDep, CallerDep, SessionDep, SettingsDep
from backend.errors import Conflict, Invalid, NotFound
from backend.schemas import DbId, PathId, QueryId, Seed
from backend.services import attempts, robots, snapshots
from core.robots import worker_drives

router = APIRouter(tags=["attempts"])

CommandWord = Annotated[str, StringConstraints(min_length=1, max_length=100)]
TaskId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="the task_id POST …/attempts answered")]
Skipped = Annotated[list[DbId] | None, Query(max_length=100, description="attempts skipped this visit")]
MAX_ATTEMPTS = 100


class AttemptsRequest(BaseModel):
    count: int = Field(ge=1, le=MAX_ATTEMPTS, description="how many attempts, spread over the commands")
    random_share: float = Field(
        default=0.25,
        ge=0.0,
        le=0.9,
        description="share of random-exploration views added beside the attempts (the 'nothing' case)",
    )
    commands: list[CommandWord] | None = Field(
        default=None, max_length=50, description="command names (or keys) to attempt; default: every one"
    )
    seed: Seed | None = Field(
        default=None,
        description="the same seed with the same model, commands and answers so far gives the same attempts "
        "and random views (to compare two fine-tunes on the same labels); default: new ones each time",
    )


class AttemptsQueued(BaseModel):
    task_id: str
    robot_id: int
    attempts: int
    random_views: int
    commands: list[str] = Field(description="the names of the commands the robot will try")
    queue: str


class AttemptsStatus(BaseModel):
    task_id: str
    state: Literal["queued", "running", "done", "refused", "failed"]
    message: str
    created: int = Field(default=0, description="attempts stored as snapshots so far")
    random_views: int = 0


class CommandChoice(BaseModel):
    key: str = Field(description="what `instead` names in an answer")
    name: str
    clip_ids: list[int]


class NextAttempt(BaseModel):
    snapshot: schemas.SnapshotPublic | None = Field(description="the attempt's final view")
    asked: CommandChoice | None = Field(description="the command the robot was given")
    clip_id: int | None = Field(description="the recording of it the robot heard: play this one")
    others: list[CommandChoice] = Field(description="what a 'no' may say the view shows instead, in order")
    frames: list[str] = Field(description="URLs of the attempt's replay frames, the final view last")
    message: str


class AttemptAnswer(BaseModel):
    answer: Literal["yes", "no"]
    instead: CommandWord | None = Field(
        default=None, description=f"after 'no': another command's key, or {attempts.NOTHING!r}"
    )


class AnswerStored(BaseModel):
    shows: str = Field(description="what the answer says the view shows: a command's name, or 'nothing'")
    labels: list[schemas.LabelPublic] = Field(description="undo: DELETE /labels/{id} for each")


@router.post(
    "/robots/{robot_id}/attempts",
    response_model=AttemptsQueued,
    status_code=status.HTTP_202_ACCEPTED,
    responses=errors(409, 429, 503),
)
def ask_for_attempts(
    robot_id: PathId, body: AttemptsRequest, caller: CallerDep, session: SessionDep, settings: SettingsDep
) -> AttemptsQueued:
    """Ask the robot worker to try the household's recorded commands with the robot's active policy (or its
    base model): each attempt's final view becomes a snapshot to judge, with a short replay of the attempt;
    random-exploration views join them (`random_share`). Follow it with GET …/attempts/{task_id}. The views
    count against the household's hourly capture quota (429 beyond it)."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    if not worker_drives(robot.kind, robot.settings or {}):
        raise Conflict(
            f"robot {robot.id} is a real {robot.kind}: attempts are made by simulated robots, or by a real "
            "arm the robot worker drives (set its arm_ip), or capture its camera frames (POST …/snapshots)"
        )
    command_keys = attempts.check_commands(session, caller.household_id, body.commands)
    random_views = attempts.random_view_count(body.count, body.random_share)
    if body.count + random_views > settings.max_capture_count:
        raise Invalid(f"at most {settings.max_capture_count} views per request; ask for fewer")
    task_id = uuid.uuid4().hex
    attempts.ask_for_attempts(
        robot, command_keys, body.count, random_views, settings.capture_views_per_hour, task_id, body.seed
    )
    names = attempts.household_commands(session, caller.household_id)
    return AttemptsQueued(
        task_id=task_id,
        robot_id=robot.id,
        attempts=body.count,
        random_views=random_views,
        commands=[names[key].name for key in command_keys],
        queue=broker.QUEUE_ROBOT,
    )


@router.get("/robots/{robot_id}/attempts/{task_id}", response_model=AttemptsStatus, responses=errors(503))
def attempts_status(
    robot_id: PathId, task_id: TaskId, caller: CallerDep, session: SessionDep
) -> AttemptsStatus:
    """Where an attempts task stands; a refused one says why and what to do (e.g. a robot with no model)."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    found = attempts.read_status(task_id)
    if found is None or found.get("robot_id") != robot.id:
        raise NotFound("attempts task", task_id)
    return AttemptsStatus(task_id=task_id, **{k: v for k, v in found.items() if k != "robot_id"})


@router.get("/attempts/next", response_model=NextAttempt, responses=errors(404))
def next_attempt(
    caller: CallerDep,
    session: SessionDep,
    robot_id: QueryId = None,
    skip: Skipped = None,
) -> NextAttempt:
    """The next attempt to judge: its final view, the command the robot was given, its replay frames and the
    other commands a 'no' may name."""
    if robot_id is not None:
        robots.get_robot(session, caller.household_id, robot_id)
    choice = attempts.next_attempt(session, caller.user_id, caller.household_id, robot_id, skip)
    if choice is None:
        return NextAttempt(
            snapshot=None, asked=None, clip_id=None, others=[], frames=[],
            message="no attempts left to judge: ask the robot to try your commands "
            "(POST /api/v1/robots/{robot_id}/attempts, or the button on this page)",
        )  # fmt: skip
    snapshot = choice.snapshot
    attempt = attempts.attempt_of(snapshot)
    clip_id = int(attempt.get("clip_id") or 0)
    return NextAttempt(
        snapshot=schemas.SnapshotPublic.model_validate(snapshot),
        asked=_choice(choice.asked),
        clip_id=clip_id if clip_id in choice.asked.clip_ids else choice.asked.clip_ids[0],
        others=[_choice(command) for command in choice.others],
        frames=[
            f"/api/v1/attempts/{snapshot.id}/frames/{i}" for i in range(len(attempt.get("frames") or []))
        ],
        message=f"the robot was asked “{choice.asked.name}”: did it do what you said?",
    )


def _choice(command: attempts.Command) -> CommandChoice:
    return CommandChoice(key=command.key, name=command.name, clip_ids=list(command.clip_ids))


@router.post(
    "/attempts/{snapshot_id}/answer",
    response_model=AnswerStored,
    status_code=status.HTTP_201_CREATED,
    responses=errors(409),
)
def answer_attempt(
    snapshot_id: PathId, body: AttemptAnswer, caller: CallerDep, session: SessionDep
) -> AnswerStored:
    """*yes*: is for the asked command, is not for the others; *no* + another command: is for that one, is
    not for the rest; *no* + nothing: is not for every command. All on the attempt's final view."""
    snapshot = snapshots.get_snapshot(session, caller.household_id, snapshot_id)
    attempts.attempt_of(snapshot)
    stored = attempts.answer_attempt(
        session, caller.user_id, caller.household_id, snapshot, body.answer == "yes", body.instead
    )
    return AnswerStored(
        shows=stored.shows, labels=[schemas.LabelPublic.model_validate(label) for label in stored.labels]
    )


@router.get(
    "/attempts/{snapshot_id}/frames/{index}",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **errors(206, 304, 410, 416)},
)
def attempt_frame(
    snapshot_id: PathId,
    index: Annotated[int, Path(ge=0, le=1000)],
    request: Request,
    caller: CallerDep,
    session: SessionDep,
    blobs: BlobsDep,
) -> Response:
    """One frame of an attempt's replay (PNG), the final view last."""
    snapshot = snapshots.get_snapshot(session, caller.household_id, snapshot_id)
    key = attempts.frame_key(snapshot, index)
    return ranged_response(request, blobs.get(key), "image/png", key)
