"""Model versions per robot: candidate → active → retired, activation and rollback, stored embeddings."""

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from backend import models, scene_requests
from backend.errors import Conflict, Invalid, NotFound
from backend.schemas import ModelVersionPublic


def public(version: models.ModelVersion) -> ModelVersionPublic:
    return ModelVersionPublic.model_validate(
        {
            **{column.key: getattr(version, column.key) for column in models.ModelVersion.__table__.columns},
            "has_var": version.var_key is not None,
            "has_policy": version.policy_key is not None,
        }
    )


def get_version(session: Session, household_id: int, version_id: int) -> models.ModelVersion:
    version = session.get(models.ModelVersion, version_id)
    if version is None or version.household_id != household_id:
        raise NotFound("model version", version_id)
    return version


def list_versions(session: Session, robot: models.Robot) -> list[models.ModelVersion]:
    query = select(models.ModelVersion).where(models.ModelVersion.robot_id == robot.id)
    return list(session.scalars(query.order_by(models.ModelVersion.id.desc())))


def active_version(session: Session, robot_id: int) -> models.ModelVersion | None:
    return session.scalar(
        select(models.ModelVersion).where(
            models.ModelVersion.robot_id == robot_id, models.ModelVersion.status == models.ModelStatus.ACTIVE
        )
    )


def create_version(
    session: Session,
    robot: models.Robot,
    *,
    var_key: str | None,
    policy_key: str | None,
    parent_id: int | None = None,
    run_id: int | None = None,
    metrics: dict[str, Any] | None = None,
    notes: str | None = None,
) -> models.ModelVersion:
    """For workers: a new candidate (promotion is a separate, explicit step)."""
    version = models.ModelVersion(
        household_id=robot.household_id,
        robot_id=robot.id,
        parent_id=parent_id,
        run_id=run_id,
        status=models.ModelStatus.CANDIDATE,
        var_key=var_key,
        policy_key=policy_key,
        metrics=metrics or {},
        notes=notes,
    )
    session.add(version)
    session.flush()
    return version


def activate(session: Session, version: models.ModelVersion) -> models.ModelVersion:
    current = active_version(session, version.robot_id)
    if current is not None and current.id == version.id:
        return version
    if version.var_key is None:
        raise Conflict(f"model version {version.id} has no VAR weights and cannot drive the robot")
    _switch(session, current, version)
    version.previous_active_id = current.id if current is not None else version.previous_active_id
    session.commit()
    scene_requests.ask_to_refresh(version.household_id)  # the scene shows the new model at once
    return version


def rollback(session: Session, robot: models.Robot) -> models.ModelVersion:
    current = active_version(session, robot.id)
    if current is None or current.previous_active_id is None:
        raise Conflict(f"“{robot.name}” has no earlier version in use to go back to")
    target = session.get_one(models.ModelVersion, current.previous_active_id)
    _switch(session, current, target)
    session.commit()
    scene_requests.ask_to_refresh(robot.household_id)
    return target


def _switch(session: Session, current: models.ModelVersion | None, target: models.ModelVersion) -> None:
    if current is not None:
        current.status = models.ModelStatus.RETIRED
        session.flush()  # free the robot's one "active" slot before taking it
    target.status = models.ModelStatus.ACTIVE
    target.activated_at = datetime.now(UTC)
    session.flush()


def embeddings(
    session: Session, version: models.ModelVersion
) -> tuple[dict[int, list[float]], dict[int, list[float]]]:
    snapshots: dict[int, list[float]] = {}
    clips: dict[int, list[float]] = {}
    query = select(models.Embedding.snapshot_id, models.Embedding.clip_id, models.Embedding.vector).where(
        models.Embedding.model_version_id == version.id
    )
    for snapshot_id, clip_id, vector in session.execute(query):
        if snapshot_id is not None:
            snapshots[snapshot_id] = vector
        else:
            clips[clip_id] = vector
    return snapshots, clips


def store_embeddings(
    session: Session,
    version: models.ModelVersion,
    snapshots: dict[int, list[float]],
    clips: dict[int, list[float]],
) -> int:
    """Replace the stored position of each given snapshot / clip (workers call this after embedding them)."""
    _check_owned(session, models.Snapshot, version.household_id, snapshots)
    _check_owned(session, models.Clip, version.household_id, clips)
    lengths = {len(vector) for vector in [*snapshots.values(), *clips.values()]}
    if len(lengths) > 1:
        raise Invalid(f"all embeddings of one model must have the same length, got {sorted(lengths)}")
    for column, items in ((models.Embedding.snapshot_id, snapshots), (models.Embedding.clip_id, clips)):
        if items:
            session.execute(
                delete(models.Embedding).where(
                    models.Embedding.model_version_id == version.id, column.in_(list(items))
                )
            )
    session.add_all(
        [models.Embedding(model_version_id=version.id, snapshot_id=i, vector=v) for i, v in snapshots.items()]
        + [models.Embedding(model_version_id=version.id, clip_id=i, vector=v) for i, v in clips.items()]
    )
    session.commit()
    return len(snapshots) + len(clips)


def _check_owned(
    session: Session, table: type[models.Snapshot] | type[models.Clip], household_id: int, ids: dict
) -> None:  # type: ignore[type-arg]
    if not ids:
        return
    found = set(
        session.scalars(select(table.id).where(table.id.in_(list(ids)), table.household_id == household_id))
    )
    missing = sorted(set(ids) - found)
    if missing:
        raise NotFound(table.__tablename__.rstrip("s"), ", ".join(map(str, missing[:10])))
