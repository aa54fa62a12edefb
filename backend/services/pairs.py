"""Which (image, clip) pair to ask a member about next: balanced across the household's commands, or, once an
active model has embedded the household's data, the image that sits most nearly between two commands on the
sphere. A pair just handed to another member is passed over while that member answers it (`pair_leases`).
"""

import random
from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import Select, bindparam, exists, select
from sqlalchemy.orm import Session

from backend import models
from backend.schemas import ClipPublic, SnapshotPublic
from backend.services.pair_leases import pair_leases
from core.labels import command_key

_TOP_CANDIDATES = 8  # images considered per clip; enough for several members labelling at once

_SNAPSHOT_COLUMNS = [getattr(models.Snapshot, name) for name in SnapshotPublic.model_fields]
_CLIP_COLUMNS = [getattr(models.Clip, name) for name in ClipPublic.model_fields]


@dataclass(frozen=True)
class PairChoice:
    snapshot: dict[str, Any]  # the fields of SnapshotPublic
    clip: dict[str, Any]  # the fields of ClipPublic
    strategy: str
    informativeness: float | None = None


@dataclass(frozen=True)
class _Command:
    clip_id: int
    name: str | None
    command_clip_ids: tuple[int, ...]  # every live clip of the same command, this one included


_LIVE_CLIPS = select(models.Clip.id, models.Clip.name, models.Clip.label_count).where(
    models.Clip.household_id == bindparam("household_id"), models.Clip.deleted_at.is_(None)
)


def _clips_in_asking_order(session: Session, household_id: int) -> list[_Command]:
    """Least-answered command first, and within it the least-answered clip: balanced across commands."""
    rows = session.connection().execute(_LIVE_CLIPS, {"household_id": household_id}).all()
    per_command: Counter[str] = Counter()
    siblings: defaultdict[str, list[int]] = defaultdict(list)
    for clip_id, name, answered in rows:
        per_command[command_key(clip_id, name)] += answered
        siblings[command_key(clip_id, name)].append(clip_id)
    random.shuffle(rows)  # ties are broken at random
    rows.sort(key=lambda row: (per_command[command_key(row[0], row[1])], row[2]))
    return [_Command(clip_id, name, tuple(siblings[command_key(clip_id, name)])) for clip_id, name, _ in rows]


def _candidates(robot: bool, whole_command: bool) -> Select[Any]:
    """Live images not yet answered for one clip — or, with `whole_command`, for any clip of its command —,
    most-answered first (answering every command about one image completes its triplets). Only (count, id):
    the database sorts the ties of one count by id."""
    answered = (
        models.Label.clip_id.in_(bindparam("command_clip_ids", expanding=True))
        if whole_command
        else models.Label.clip_id == bindparam("clip_id")
    )
    query = (
        select(models.Snapshot.label_count, models.Snapshot.id)
        .where(
            models.Snapshot.household_id == bindparam("household_id"),
            models.Snapshot.deleted_at.is_(None),
            ~exists().where(models.Label.snapshot_id == models.Snapshot.id, answered),
        )
        .order_by(models.Snapshot.label_count.desc(), models.Snapshot.id)
        .limit(_TOP_CANDIDATES)
    )
    return query.where(models.Snapshot.robot_id == bindparam("robot_id")) if robot else query


# One answer per command and image comes first: an image with nothing the household says needs one "is not"
# per command to become a silence triplet, and more images answered means more of the rare views that show
# a command's target. Other speakers' clips of the same command are asked about after that.
_CANDIDATES = {
    (robot, whole_command): _candidates(robot, whole_command)
    for robot in (False, True)
    for whole_command in (True, False)
}
_PAIR = (
    select(*_SNAPSHOT_COLUMNS, *(column.label(f"clip_{column.key}") for column in _CLIP_COLUMNS))
    .join(models.Clip, models.Clip.id == bindparam("clip_id"))
    .where(models.Snapshot.id == bindparam("snapshot_id"))
)


def _pair(session: Session, snapshot_id: int, clip_id: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The public fields of one snapshot and one clip, in one query."""
    row = session.connection().execute(_PAIR, {"snapshot_id": snapshot_id, "clip_id": clip_id}).one()
    split = len(_SNAPSHOT_COLUMNS)
    snapshot = dict(zip(SnapshotPublic.model_fields, row[:split], strict=True))
    clip = dict(zip(ClipPublic.model_fields, row[split:], strict=True))
    return snapshot, clip


def next_pair(session: Session, user_id: int, household_id: int, robot_id: int | None) -> PairChoice | None:
    """The pair to ask this member next, claimed for them (`pair_leases`): a pair another member of the
    household holds is passed over while that member answers it; if every candidate is taken, one is asked
    anyway."""
    clips = _clips_in_asking_order(session, household_id)
    if not clips:
        return None
    return _informative_pair(session, user_id, household_id, robot_id, clips) or _balanced_pair(
        session, user_id, household_id, robot_id, clips
    )


def _balanced_pair(
    session: Session, user_id: int, household_id: int, robot_id: int | None, clips: list[_Command]
) -> PairChoice | None:
    connection = session.connection()
    fallback: tuple[int, int] | None = None
    for whole_command in (True, False):
        query = _CANDIDATES[robot_id is not None, whole_command]
        for clip in clips:
            parameters = {
                "household_id": household_id,
                "robot_id": robot_id,
                "clip_id": clip.clip_id,
                "command_clip_ids": list(clip.command_clip_ids),
            }
            rows = connection.execute(query, parameters).all()
            if not rows:
                continue
            best = rows[0][0]
            most_answered = [row[1] for row in rows if row[0] == best]
            random.shuffle(most_answered)  # the most-answered images first, in random order, then the rest
            for snapshot_id in [*most_answered, *(row[1] for row in rows if row[0] != best)]:
                if pair_leases.claim((household_id, snapshot_id, clip.clip_id), user_id):
                    return PairChoice(*_pair(session, snapshot_id, clip.clip_id), "balanced")
            fallback = fallback or (most_answered[0], clip.clip_id)
    return None if fallback is None else PairChoice(*_pair(session, *fallback), "balanced")


def _active_models(robot: bool) -> Select[Any]:
    query = select(models.ModelVersion.id, models.ModelVersion.robot_id).where(
        models.ModelVersion.household_id == bindparam("household_id"),
        models.ModelVersion.status == models.ModelStatus.ACTIVE,
    )
    return query.where(models.ModelVersion.robot_id == bindparam("robot_id")) if robot else query


_ACTIVE_MODELS = {robot: _active_models(robot) for robot in (False, True)}


def _informative_pair(
    session: Session, user_id: int, household_id: int, robot_id: int | None, clips: list[_Command]
) -> PairChoice | None:
    """Once an active model has embedded the household's data: the unanswered (image, clip) whose image
    sits most nearly between the clip's command cluster and another command's cluster on the sphere."""
    active = session.connection().execute(
        _ACTIVE_MODELS[robot_id is not None], {"household_id": household_id, "robot_id": robot_id}
    )
    for model_id, model_robot_id in active.all():
        clip_vectors = dict(
            session.execute(
                select(models.Embedding.clip_id, models.Embedding.vector).where(
                    models.Embedding.model_version_id == model_id, models.Embedding.clip_id.is_not(None)
                )
            ).all()
        )
        groups: dict[str, list[list[float]]] = defaultdict(list)
        for clip in clips:
            if clip.clip_id in clip_vectors:
                groups[command_key(clip.clip_id, clip.name)].append(clip_vectors[clip.clip_id])
        if len(groups) < 2:
            continue
        keys = list(groups)
        centroids = _unit(np.array([np.mean(groups[key], axis=0) for key in keys]))
        snapshot_rows = session.execute(
            select(models.Embedding.snapshot_id, models.Embedding.vector)
            .join(models.Snapshot, models.Snapshot.id == models.Embedding.snapshot_id)
            .where(
                models.Embedding.model_version_id == model_id,
                models.Snapshot.deleted_at.is_(None),
                models.Snapshot.robot_id == model_robot_id,
            )
        ).all()
        if not snapshot_rows:
            continue
        snapshot_ids = np.array([row[0] for row in snapshot_rows])
        similarity = _unit(np.array([row[1] for row in snapshot_rows])) @ centroids.T  # (snapshots, commands)
        answered = set(
            session.execute(
                select(models.Label.snapshot_id, models.Label.clip_id).where(
                    models.Label.household_id == household_id,
                    models.Label.snapshot_id.in_(snapshot_ids.tolist()),
                )
            ).all()
        )
        best: tuple[float, int, int] | None = None
        for clip in clips:
            key = command_key(clip.clip_id, clip.name)
            if key not in groups:
                continue
            column = keys.index(key)
            others = np.delete(similarity, column, axis=1).max(axis=1)
            # 1 when the image is as close to this command as to its nearest rival, 0 at opposite poles.
            score = 1.0 - np.abs(similarity[:, column] - others) / 2.0
            for index in np.argsort(-score)[: _TOP_CANDIDATES * 4]:
                snapshot_id = int(snapshot_ids[index])
                if (snapshot_id, clip.clip_id) not in answered and not pair_leases.held_by_another(
                    (household_id, snapshot_id, clip.clip_id), user_id
                ):
                    if best is None or score[index] > best[0]:
                        best = (float(score[index]), snapshot_id, clip.clip_id)
                    break
        # Claimed only now (one pair, not every candidate looked at); lost to a faster member: ask another.
        if best is not None and pair_leases.claim((household_id, best[1], best[2]), user_id):
            score, snapshot_id, clip_id = best
            return PairChoice(*_pair(session, snapshot_id, clip_id), "informative", score)
    return None


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)
