"""The household's 3D scene, asked through Redis (`backend.scene_requests`): "try it now" with a live voice
(the robot carries out what a member just said; the clip is kept nowhere) and which robot the scene shows.
The scene is started on demand when none runs (`scene.on_demand`)."""

from typing import Annotated, Literal, NoReturn

from fastapi import APIRouter, File, Form, Path, UploadFile, status
from pydantic import BaseModel, Field

from backend import audio, scene_requests
from backend.api.responses import errors
from backend.deps import CallerDep, SessionDep, SettingsDep
from backend.errors import ApiError, NotFound, Unavailable
from backend.schemas import MAX_ID, DbId
from backend.services import robots
from scene import on_demand
from scene.endpoint import announced

router = APIRouter(prefix="/scene", tags=["scene"])

TryId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="the try_id POST /scene/tries answered")]


class TryStatus(BaseModel):
    try_id: str
    state: Literal["starting", "running", "done", "refused", "failed"]
    message: str = Field(description="what is happening, in the household's words")
    step: int = 0
    steps: int = 0
    finished: bool


class ShownRobot(BaseModel):
    robot_id: int | None = Field(description="the robot the scene shows (null: no scene runs right now)")


class RobotChoice(BaseModel):
    robot_id: DbId


class VoiceRejected(ApiError):
    def __init__(self, detail: str, status_code: int) -> None:
        super().__init__(detail)
        self.status_code = status_code


def _scene_asked(call: str) -> NoReturn:
    """Turn Redis being away into a 503 that says what to do."""
    raise Unavailable(f"{call}: the 3D scene cannot be reached right now (Redis is down); try again shortly")


def _wake_scene(household_id: int) -> bool:
    """Start the household's scene when none runs; True when it still has to come up."""
    if announced(household_id) is not None:
        return False
    on_demand.start_for(household_id)
    return True


@router.post(
    "/tries",
    response_model=TryStatus,
    status_code=status.HTTP_202_ACCEPTED,
    responses=errors(404, 413, 415, 422, 503),
)
def try_it_now(
    file: Annotated[UploadFile, File(description=f"what was just said ({audio.ACCEPTED}), 0.3–10 s")],
    caller: CallerDep,
    session: SessionDep,
    settings: SettingsDep,
    robot_id: Annotated[
        int | None, Form(ge=1, le=MAX_ID, description="the robot to carry it out (default: the scene's)")
    ] = None,
) -> TryStatus:
    """The household's robot, in its scene, carries out what was just said. The clip is not kept: it goes to
    the scene and nowhere else. Follow it with GET /scene/tries/{try_id}."""
    if robot_id is not None:
        robots.get_robot(session, caller.household_id, robot_id)
    data = file.file.read(settings.max_clip_bytes + 1)
    try:
        clip = audio.validate_and_normalise(
            data,
            min_seconds=settings.min_clip_seconds,
            max_seconds=settings.max_clip_seconds,
            max_bytes=settings.max_clip_bytes,
        )
    except audio.AudioRejected as exc:
        raise VoiceRejected(str(exc), exc.status_code) from exc
    message = scene_requests.STARTING_MESSAGE
    if _wake_scene(caller.household_id):
        message = "Starting your household's 3D scene first (a few seconds), then the robot carries it out…"
    try:
        try_id = scene_requests.ask_to_try(caller.household_id, robot_id, clip.wav, message)
    except scene_requests.SceneUnreachable:
        _scene_asked("try it now")
    return TryStatus(try_id=try_id, state="starting", message=message, finished=False)


@router.get("/tries/{try_id}", response_model=TryStatus, responses=errors(404, 503))
def try_status(try_id: TryId, caller: CallerDep) -> TryStatus:
    try:
        found = scene_requests.read_try(try_id, caller.household_id)
    except scene_requests.SceneUnreachable:
        _scene_asked("reading the try")
    if found is None:
        raise NotFound("try", try_id)
    return TryStatus(
        try_id=try_id,
        state=found["state"],
        message=found["message"],
        step=found.get("step", 0),
        steps=found.get("steps", 0),
        finished=found["state"] in scene_requests.FINISHED,
    )


@router.get("/robot", response_model=ShownRobot)
def shown_robot(caller: CallerDep) -> ShownRobot:
    return ShownRobot(robot_id=scene_requests.read_shown_robot(caller.household_id))


@router.put(
    "/robot", response_model=ShownRobot, status_code=status.HTTP_202_ACCEPTED, responses=errors(404, 503)
)
def show_robot(choice: RobotChoice, caller: CallerDep, session: SessionDep) -> ShownRobot:
    """Show this robot of the household in its scene (the Scene page starts the scene when none runs; a scene
    that starts within a couple of minutes still takes the choice)."""
    robots.get_robot(session, caller.household_id, choice.robot_id)
    try:
        scene_requests.ask(caller.household_id, {"type": "show_robot", "robot_id": choice.robot_id})
    except scene_requests.SceneUnreachable:
        _scene_asked("choosing the robot")
    return ShownRobot(robot_id=choice.robot_id)
