import uuid
from typing import Annotated, Literal

from fastapi import APIRouter, Path, status
from pydantic import BaseModel, Field

from backend import broker, schemas
from backend.api.responses import errors
from backend.deps import AdminDep, CallerDep, SessionDep
from backend.errors import NotFound
from backend.schemas import PathId, Seed
from backend.services import model_versions, robots
from backend.services.room_adaptation import adaptation_status, ask_to_adapt
from core.rooms import MIN_ROOM_VIEWS, ROOM_VIEWS

router = APIRouter(tags=["models"])
TaskId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="what POST …:adapt-to-room answered")]


class AdaptRequest(BaseModel):
    views: int = Field(
        default=ROOM_VIEWS, ge=MIN_ROOM_VIEWS, le=5000, description="how many views of the room to use"
    )
    share: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="how far the statistics move toward the room's (1: all the way; 0: back to the base "
        "model's, for a robot back in its training room, and no views are needed)",
    )
    seed: Seed | None = Field(
        default=None,
        description="a simulated robot's random moves: the same seed renders the same views, so the same "
        "adaptation (none: a fresh draw each time; a real robot's views are its newest frames, seed or not)",
    )


class AdaptQueued(BaseModel):
    task_id: str
    robot_id: int
    views: int = Field(
        description="the views it will use: rendered for a simulated robot; a real one's newest frames, at "
        "most the number asked; none for share 0"
    )
    queue: str


class AdaptStatus(BaseModel):
    task_id: str
    state: Literal["queued", "running", "done", "refused", "failed"]
    message: str
    version_id: int | None = Field(default=None, description="the adapted version, made active (when done)")


@router.get("/robots/{robot_id}/models", response_model=list[schemas.ModelVersionPublic])
def list_versions(
    robot_id: PathId, caller: CallerDep, session: SessionDep
) -> list[schemas.ModelVersionPublic]:
    robot = robots.get_robot(session, caller.household_id, robot_id)
    return [model_versions.public(v) for v in model_versions.list_versions(session, robot)]


@router.post(
    "/robots/{robot_id}/models:rollback", response_model=schemas.ModelVersionPublic, responses=errors(409)
)
def rollback(robot_id: PathId, caller: AdminDep, session: SessionDep) -> schemas.ModelVersionPublic:
    """Make the version that was active before the current one active again (admins)."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    return model_versions.public(model_versions.rollback(session, robot))


@router.post(
    "/robots/{robot_id}/models:adapt-to-room",
    response_model=AdaptQueued,
    status_code=status.HTTP_202_ACCEPTED,
    responses=errors(409, 503),
)
def adapt_to_room(robot_id: PathId, body: AdaptRequest, caller: AdminDep, session: SessionDep) -> AdaptQueued:
    """Adapt the robot's active model (or its base model) to the room its camera sees, no labels needed: the
    image encoder's batch-norm statistics move toward those of views of the room (a simulated robot renders
    them and stores none; a real one's newest frames are used), no weight changes. The result becomes the
    active version (rollback undoes it). After moving the robot, ask again. Follow it with GET
    …/adaptations/{task_id}."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    task_id = uuid.uuid4().hex
    views = ask_to_adapt(session, robot, body.views, body.share, task_id, body.seed)
    return AdaptQueued(task_id=task_id, robot_id=robot.id, views=views, queue=broker.QUEUE_ROBOT)


@router.get("/robots/{robot_id}/adaptations/{task_id}", response_model=AdaptStatus, responses=errors(503))
def adaptation(robot_id: PathId, task_id: TaskId, caller: CallerDep, session: SessionDep) -> AdaptStatus:
    """Where an adaptation stands; a refused one says why and what to do."""
    robot = robots.get_robot(session, caller.household_id, robot_id)
    found = adaptation_status(task_id)
    if found is None or found.get("robot_id") != robot.id:
        raise NotFound("adaptation task", task_id)
    return AdaptStatus(task_id=task_id, **{k: v for k, v in found.items() if k != "robot_id"})


@router.get("/models/{version_id}", response_model=schemas.ModelVersionPublic)
def get_version(version_id: PathId, caller: CallerDep, session: SessionDep) -> schemas.ModelVersionPublic:
    return model_versions.public(model_versions.get_version(session, caller.household_id, version_id))


@router.post(
    "/models/{version_id}:activate", response_model=schemas.ModelVersionPublic, responses=errors(409)
)
def activate(version_id: PathId, caller: AdminDep, session: SessionDep) -> schemas.ModelVersionPublic:
    version = model_versions.get_version(session, caller.household_id, version_id)
    return model_versions.public(model_versions.activate(session, version))


@router.get("/models/{version_id}/embeddings", response_model=schemas.EmbeddingsPublic)
def get_embeddings(version_id: PathId, caller: CallerDep, session: SessionDep) -> schemas.EmbeddingsPublic:
    """Where this version puts the household's snapshots and clips on its sphere."""
    version = model_versions.get_version(session, caller.household_id, version_id)
    snapshots, clips = model_versions.embeddings(session, version)
    return schemas.EmbeddingsPublic(model_version_id=version.id, snapshots=snapshots, clips=clips)


@router.put("/models/{version_id}/embeddings", response_model=schemas.EmbeddingsPublic)
def put_embeddings(
    version_id: PathId, body: schemas.EmbeddingsUpdate, caller: AdminDep, session: SessionDep
) -> schemas.EmbeddingsPublic:
    """Store embeddings computed by a worker (replaces those of the same snapshots / clips)."""
    version = model_versions.get_version(session, caller.household_id, version_id)
    model_versions.store_embeddings(session, version, body.snapshots, body.clips)
    snapshots, clips = model_versions.embeddings(session, version)
    return schemas.EmbeddingsPublic(model_version_id=version.id, snapshots=snapshots, clips=clips)
