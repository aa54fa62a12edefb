"""What the scene shows of one household, read from the database and the blob store: its robots, clips
(grouped into commands), snapshots, the active model version, stored embeddings, and its runs."""

from dataclasses import dataclass, field

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.blobs import BlobNotFound, LocalBlobStore
from backend.db import get_session_factory
from backend.settings import get_settings
from core.labels import command_key

MAX_SNAPSHOTS = 400


@dataclass
class ClipInfo:
    id: int
    title: str
    command: str  # the command this clip belongs to (its name, else the clip itself)
    speaker: str


@dataclass
class HouseholdView:
    household_id: int
    robot: models.Robot | None
    clips: list[ClipInfo] = field(default_factory=list)
    snapshot_ids: list[int] = field(default_factory=list)
    model: models.ModelVersion | None = None
    clip_vectors: dict[int, np.ndarray] = field(default_factory=dict)  # stored by a worker for the model
    snapshot_vectors: dict[int, np.ndarray] = field(default_factory=dict)
    running_run: models.Run | None = None

    @property
    def commands(self) -> list[str]:
        return sorted({clip.command for clip in self.clips})


def blob_store() -> LocalBlobStore:
    return LocalBlobStore(get_settings().blob_path)


def default_household_id() -> int | None:
    with get_session_factory()() as session:
        return session.scalar(select(models.Household.id).order_by(models.Household.id).limit(1))


def _most_recently_activated(session: Session, robots: list[models.Robot]) -> models.Robot | None:
    """With no robot asked for, the scene shows the robot whose model was made active last: the one the
    household is working with."""
    by_id = {robot.id: robot for robot in robots}
    newest = session.scalar(
        select(models.ModelVersion.robot_id)
        .where(
            models.ModelVersion.robot_id.in_(list(by_id)),
            models.ModelVersion.status == models.ModelStatus.ACTIVE,
        )
        .order_by(models.ModelVersion.activated_at.desc(), models.ModelVersion.id.desc())
        .limit(1)
    )
    return by_id.get(newest) if newest is not None else None


def _first_simulated(robots: list[models.Robot]) -> models.Robot | None:
    return next((r for r in robots if r.kind.endswith("-sim")), robots[0] if robots else None)


def load_view(household_id: int, robot_id: int | None) -> HouseholdView:
    with get_session_factory()() as session:
        robots = list(
            session.scalars(
                select(models.Robot)
                .where(models.Robot.household_id == household_id)
                .order_by(models.Robot.id)
            )
        )
        robot = next((r for r in robots if r.id == robot_id), None) if robot_id else None
        robot = robot or _most_recently_activated(session, robots) or _first_simulated(robots)
        view = HouseholdView(household_id=household_id, robot=robot)
        speakers = {
            user.id: user.display_name
            for user in session.scalars(select(models.User).where(models.User.household_id == household_id))
        }
        for clip in session.scalars(
            select(models.Clip)
            .where(models.Clip.household_id == household_id, models.Clip.deleted_at.is_(None))
            .order_by(models.Clip.id)
        ):
            title = clip.name or f"recording {clip.id}"
            speaker = speakers.get(clip.speaker_id, "?")
            view.clips.append(
                ClipInfo(
                    clip.id, f"{title} ({speaker}, #{clip.id})", command_key(clip.id, clip.name), speaker
                )
            )
        if robot is None:
            return view
        view.snapshot_ids = list(
            session.scalars(
                select(models.Snapshot.id)
                .where(models.Snapshot.robot_id == robot.id, models.Snapshot.deleted_at.is_(None))
                .order_by(models.Snapshot.id.desc())
                .limit(MAX_SNAPSHOTS)
            )
        )
        view.model = session.scalar(
            select(models.ModelVersion).where(
                models.ModelVersion.robot_id == robot.id,
                models.ModelVersion.status == models.ModelStatus.ACTIVE,
            )
        )
        if view.model is not None:
            for row in session.scalars(
                select(models.Embedding).where(models.Embedding.model_version_id == view.model.id)
            ):
                vector = np.asarray(row.vector, dtype=np.float32)
                if row.clip_id is not None:
                    view.clip_vectors[row.clip_id] = vector
                elif row.snapshot_id is not None:
                    view.snapshot_vectors[row.snapshot_id] = vector
        view.running_run = session.scalar(
            select(models.Run)
            .where(models.Run.robot_id == robot.id, models.Run.status == models.RunStatus.RUNNING)
            .order_by(models.Run.id.desc())
            .limit(1)
        )
        session.expunge_all()
        return view


def clip_audio(clip_ids: list[int]) -> dict[int, bytes]:
    """The normalised WAVs of these clips (missing blobs are left out)."""
    store = blob_store()
    with get_session_factory()() as session:
        keys = dict(
            session.execute(
                select(models.Clip.id, models.Clip.wav_key).where(models.Clip.id.in_(clip_ids))
            ).all()
        )
    found = {}
    for clip_id, key in keys.items():
        try:
            found[clip_id] = store.get(key)
        except BlobNotFound:
            continue
    return found


def snapshot_images(snapshot_ids: list[int]) -> dict[int, np.ndarray]:
    """Decoded RGB snapshots (missing or unreadable blobs are left out)."""
    import io

    from PIL import Image

    store = blob_store()
    with get_session_factory()() as session:
        keys = dict(
            session.execute(
                select(models.Snapshot.id, models.Snapshot.image_key).where(
                    models.Snapshot.id.in_(snapshot_ids)
                )
            ).all()
        )
    images = {}
    for snapshot_id, key in keys.items():
        try:
            with Image.open(io.BytesIO(store.get(key))) as image:
                images[snapshot_id] = np.asarray(image.convert("RGB"))
        except (BlobNotFound, OSError):
            continue
    return images


def model_bytes(model: models.ModelVersion) -> tuple[bytes | None, bytes | None]:
    store = blob_store()

    def read(key: str | None) -> bytes | None:
        if key is None:
            return None
        try:
            return store.get(key)
        except BlobNotFound:
            return None

    return read(model.var_key), read(model.policy_key)
