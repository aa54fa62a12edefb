"""Coaching the robot by voice (`backend.services.coaching`): start a session, send what you said while the
robot worked, follow it, stop it."""

import uuid
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, Path, UploadFile, status
from pydantic import BaseModel, Field, StringConstraints

from backend import models, schemas
from backend.api.responses import errors
from backend.deps import BlobsDep, CallerDep, SessionDep, SettingsDep
from backend.errors import Conflict
from backend.schemas import PathId
from backend.services import clips, coaching, robots
from backend.services.clips import ClipRejected

router = APIRouter(tags=["coaching"])

SessionId = Annotated[
    str, Path(pattern=r"^[0-9a-f]{32}$", description="the session_id POST …/coaching answered")
]
Millis = Annotated[float, Form(ge=0, le=1e14, description="milliseconds of the browser's clock (Date.now())")]


class CoachingRequest(BaseModel):
    command: Annotated[str, StringConstraints(min_length=1, max_length=100)] = Field(
        description="the command to coach, by name (or key)"
    )
    seconds: int = Field(
        default=120,
        ge=coaching.MIN_SECONDS,
        le=coaching.MAX_SECONDS,
        description="how long the session lasts",
    )
    steps_per_s: float = Field(default=5.0, ge=1.0, le=10.0, description="the robot's pace, steps a second")


class CoachingStatus(BaseModel):
    session_id: str
    state: Literal["queued", "running", "cancelling", "done", "cancelled", "refused", "failed"]
    message: str = Field(description="where the session stands, in words")
    command_name: str
    step: int = Field(description="steps the robot has taken")
    steps: int = Field(description="steps the session takes in all")
    voiced_steps: int = Field(default=0, description="steps whose reward heard your voice so far")
    labels: int = Field(default=0, description="answers your clips gave during the session")


class CoachedClip(BaseModel):
    clip: schemas.ClipPublic
    snapshot_id: int = Field(description="the view it was said over, now labelled")
    label: int = Field(description="the *is* label's id (undo: DELETE /labels/{id})")
    step: int
    message: str


@router.post(
    "/robots/{robot_id}/coaching",
    response_model=CoachingStatus,
    status_code=status.HTTP_202_ACCEPTED,
    responses=errors(409, 503),
)
def start_coaching(
    robot_id: PathId, body: CoachingRequest, caller: CallerDep, session: SessionDep
) -> CoachingStatus:
    """Start a coaching session: the robot worker plays the robot's model on the command at a pace a person
    can follow, and the scene shows it. Hold Space (POST …/clips) while it is where it should be."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    if not models.RobotKind(robot.kind).simulated:
        raise Conflict(
            f"{robot.name} is not a simulated robot: coaching by voice is for simulated robots yet"
        )
    command = coaching.command_to_coach(session, caller.household_id, body.command)
    session_id = uuid.uuid4().hex
    coaching.start_session(robot, command, caller.user_id, body.seconds, body.steps_per_s, session_id)
    return _status(session_id, coaching.session_of(session_id, robot))


@router.get("/robots/{robot_id}/coaching/{session_id}", response_model=CoachingStatus, responses=errors(503))
def coaching_status(
    robot_id: PathId, session_id: SessionId, caller: CallerDep, session: SessionDep
) -> CoachingStatus:
    robot = robots.get_robot(session, caller.household_id, robot_id)
    return _status(session_id, coaching.session_of(session_id, robot))


@router.post(
    "/robots/{robot_id}/coaching/{session_id}/cancel", response_model=CoachingStatus, responses=errors(503)
)
def cancel_coaching(
    robot_id: PathId, session_id: SessionId, caller: CallerDep, session: SessionDep
) -> CoachingStatus:
    """Stop the session at the robot's next step; every answer already given stays."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    found = coaching.session_of(session_id, robot)
    if found["state"] in coaching.ACTIVE_STATES:
        coaching.ask_to_stop(session_id)
        found = {**found, "state": "cancelling", "message": "stopping at the robot's next step"}
        if found.get("step", 0) == 0:
            coaching.write_status(session_id, found)
    return _status(session_id, found)


@router.post(
    "/robots/{robot_id}/coaching/{session_id}/clips",
    response_model=CoachedClip,
    status_code=status.HTTP_201_CREATED,
    responses=errors(409, 413, 415, 503),
)
def send_clip(
    robot_id: PathId,
    session_id: SessionId,
    file: Annotated[UploadFile, File(description="what you said, a WAV (0.3–10 s)")],
    said_from_ms: Millis,
    said_to_ms: Millis,
    sent_at_ms: Millis,
    caller: CallerDep,
    session: SessionDep,
    blobs: BlobsDep,
    settings: SettingsDep,
) -> CoachedClip:
    """What you said while the robot worked: a recording of the coached command, an *is* answer for the
    view it was said over, and the current sound of the robot's reward for the steps it overlaps."""
    received_at = coaching.received_now()
    robot = robots.get_robot(session, caller.household_id, robot_id)
    found = coaching.session_of(session_id, robot)
    said = coaching.spoken_times(said_from_ms, said_to_ms, sent_at_ms, received_at)
    data = file.file.read(settings.max_clip_bytes + 1)
    if len(data) > settings.max_clip_bytes:
        raise ClipRejected("the recording is too large: let go of Space sooner", 413)

    def store_clip() -> models.Clip:
        name = found["command_name"]
        return clips.create_clip(session, blobs, settings, caller.user, "coaching.wav", data, name)

    answer = coaching.take_clip(session, blobs, robot, session_id, found, said, store_clip)
    return CoachedClip(
        clip=schemas.ClipPublic.model_validate(answer.clip),
        snapshot_id=answer.snapshot.id,
        label=answer.label_id,
        step=answer.step,
        message=f"Heard you over step {answer.step}: saved as “{found['command_name']}” for that view.",
    )


def _status(session_id: str, found: dict) -> CoachingStatus:
    fields = CoachingStatus.model_fields
    return CoachingStatus(session_id=session_id, **{k: v for k, v in found.items() if k in fields})
