from fastapi import APIRouter

from backend import schemas
from backend.api.responses import errors
from backend.deps import AdminDep, CallerDep, SessionDep
from backend.schemas import PathId
from backend.services import model_versions, robots

router = APIRouter(tags=["models"])


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
