"""Pair labels (is / is not), their history, which pair to ask about next, and the triplets they yield.

A triplet (image, positive sound, negative sound) comes from a snapshot with at least one *is* clip and
one *is not* clip (|is| × |is not| triplets). A snapshot answered *is not* for every command of the
household shows "nothing I said": silence is its positive, each *is not* clip a negative. A command is a
clip's name when it has one (several recordings of "the red block" are one command), else the clip itself.
"""

import random
from collections import Counter, defaultdict
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import Select, and_, bindparam, exists, insert, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend import models
from backend.errors import Conflict, NotFound
from backend.schemas import ClipPublic, LabelCreate, SnapshotPublic, TripletCount, TripletStats
from backend.services.pair_leases import pair_leases

SILENCE = "silence"
_TOP_CANDIDATES = 8  # images considered per clip; enough for several members labelling at once


def command_key(clip_id: int, name: str | None) -> str:
    return f"name:{name.strip().casefold()}" if name and name.strip() else f"clip:{clip_id}"


def get_label(session: Session, household_id: int, label_id: int) -> models.Label:
    label = session.get(models.Label, label_id)
    if label is None or label.household_id != household_id:
        raise NotFound("label", label_id)
    return label


def list_labels(
    session: Session,
    household_id: int,
    snapshot_id: int | None,
    clip_id: int | None,
    labeller_id: int | None,
    limit: int,
    offset: int,
) -> list[models.Label]:
    query = select(models.Label).where(models.Label.household_id == household_id)
    for column, value in (
        (models.Label.snapshot_id, snapshot_id),
        (models.Label.clip_id, clip_id),
        (models.Label.labeller_id, labeller_id),
    ):
        if value is not None:
            query = query.where(column == value)
    return list(session.scalars(query.order_by(models.Label.id.desc()).limit(limit).offset(offset)))


def history(session: Session, label_id: int) -> list[models.LabelEvent]:
    query = (
        select(models.LabelEvent).where(models.LabelEvent.label_id == label_id).order_by(models.LabelEvent.id)
    )
    return list(session.scalars(query))


def _record(session: Session, label: models.Label, action: str, user_id: int, verdict: str | None) -> None:
    session.add(
        models.LabelEvent(
            household_id=label.household_id,
            label_id=label.id,
            snapshot_id=label.snapshot_id,
            clip_id=label.clip_id,
            action=action,
            verdict=verdict,
            user_id=user_id,
        )
    )


# The hot path (every answer) runs prebuilt Core statements: no ORM objects, one statement per question.
_PAIR_STATE = select(
    select(models.Snapshot.id)
    .where(
        models.Snapshot.id == bindparam("snapshot_id"),
        models.Snapshot.household_id == bindparam("household_id"),
        models.Snapshot.deleted_at.is_(None),
    )
    .scalar_subquery(),
    select(models.Clip.id)
    .where(
        models.Clip.id == bindparam("clip_id"),
        models.Clip.household_id == bindparam("household_id"),
        models.Clip.deleted_at.is_(None),
    )
    .scalar_subquery(),
    select(models.Label.id)
    .where(models.Label.snapshot_id == bindparam("snapshot_id"), models.Label.clip_id == bindparam("clip_id"))
    .scalar_subquery(),
)
_INSERT_LABEL = insert(models.Label).returning(models.Label.id)
_INSERT_EVENT = insert(models.LabelEvent)


def create_label(session: Session, user_id: int, household_id: int, body: LabelCreate) -> dict[str, Any]:
    """Answers one pair; returns the new label's public fields. Label counts follow by trigger (0002)."""
    pair = {"snapshot_id": body.snapshot_id, "clip_id": body.clip_id}
    connection = session.connection()
    snapshot_id, clip_id, existing = connection.execute(
        _PAIR_STATE, {**pair, "household_id": household_id}
    ).one()
    if snapshot_id is None:
        raise NotFound("snapshot", body.snapshot_id)
    if clip_id is None:
        raise NotFound("clip", body.clip_id)
    if existing is not None:
        raise Conflict(
            f"this pair is already answered (label {existing}); change it with PUT /labels/{existing}"
        )
    now = datetime.now(UTC)
    label = {
        **pair,
        "verdict": body.verdict.value,
        "labeller_id": user_id,
        "created_at": now,
        "updated_at": now,
        "updated_by_id": user_id,
    }
    try:
        label_id = connection.execute(_INSERT_LABEL, {**label, "household_id": household_id}).scalar_one()
    except IntegrityError as exc:  # answered by someone else a moment ago
        session.rollback()
        raise Conflict("this pair was just answered by someone else; fetch the next pair") from exc
    connection.execute(
        _INSERT_EVENT,
        {
            **pair,
            "household_id": household_id,
            "label_id": label_id,
            "action": "created",
            "verdict": label["verdict"],
            "user_id": user_id,
            "at": now,
        },
    )
    session.commit()
    pair_leases.release((household_id, body.snapshot_id, body.clip_id))
    return {"id": label_id, **label}


def change_label(session: Session, label: models.Label, user_id: int, verdict: str) -> models.Label:
    if label.verdict != verdict:
        label.verdict = verdict
        label.updated_at = datetime.now(UTC)
        label.updated_by_id = user_id
        _record(session, label, "changed", user_id, verdict)
        session.commit()
    return label


def delete_label(session: Session, label: models.Label, user_id: int) -> None:
    _record(session, label, "deleted", user_id, None)
    session.delete(label)
    session.commit()


# --- which pair next ----------------------------------------------------------------------------------------

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
    """The pair to ask this member next. A pair just handed to another member of the household is passed
    over while that member answers it (`pair_leases`); if every candidate is taken, one is asked anyway."""
    clips = _clips_in_asking_order(session, household_id)
    if not clips:
        return None
    choice = _informative_pair(session, user_id, household_id, robot_id, clips) or _balanced_pair(
        session, user_id, household_id, robot_id, clips
    )
    if choice is not None:
        pair_leases.grant((household_id, choice.snapshot["id"], choice.clip["id"]), user_id)
    return choice


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
                if not pair_leases.held_by_another((household_id, snapshot_id, clip.clip_id), user_id):
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
        if best is not None:
            score, snapshot_id, clip_id = best
            return PairChoice(*_pair(session, snapshot_id, clip_id), "informative", score)
    return None


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


# --- triplets -----------------------------------------------------------------------------------------------


def triplet_stats(session: Session, household_id: int, robot_id: int | None) -> TripletStats:
    clips = {
        clip_id: (command_key(clip_id, name), name or f"clip {clip_id}")
        for clip_id, name in session.execute(
            select(models.Clip.id, models.Clip.name).where(
                models.Clip.household_id == household_id, models.Clip.deleted_at.is_(None)
            )
        )
    }
    members = dict(
        session.execute(
            select(models.User.id, models.User.display_name).where(models.User.household_id == household_id)
        ).all()
    )
    live_snapshot = and_(models.Snapshot.id == models.Label.snapshot_id, models.Snapshot.deleted_at.is_(None))
    query = (
        select(models.Label.snapshot_id, models.Label.clip_id, models.Label.verdict, models.Label.labeller_id)
        .join(models.Snapshot, live_snapshot)
        .where(models.Label.household_id == household_id)
    )
    if robot_id is not None:
        query = query.where(models.Snapshot.robot_id == robot_id)
    per_snapshot: dict[int, list[tuple[int, str, int]]] = defaultdict(list)
    label_count = 0
    for snapshot_id, clip_id, verdict, labeller_id in session.execute(query):
        if clip_id in clips:  # labels of deleted clips leave training
            per_snapshot[snapshot_id].append((clip_id, verdict, labeller_id))
            label_count += 1
    all_commands = {key for key, _ in clips.values()}
    per_command: Counter[str] = Counter()
    per_member: Counter[int] = Counter()
    total = silence = used = 0
    for answers in per_snapshot.values():
        positives = [(c, who) for c, verdict, who in answers if verdict == models.Verdict.IS]
        negatives = [(c, who) for c, verdict, who in answers if verdict == models.Verdict.IS_NOT]
        if positives and negatives:
            for clip_id, who in positives:
                per_command[clips[clip_id][0]] += len(negatives)
                per_member[who] += len(negatives)
            total += len(positives) * len(negatives)
            used += 1
        elif negatives and not positives and {clips[c][0] for c, _ in negatives} >= all_commands:
            per_command[SILENCE] += len(negatives)
            for _, who in negatives:
                per_member[who] += 1
            total += len(negatives)
            silence += len(negatives)
            used += 1
    names = {key: name for key, name in clips.values()} | {SILENCE: "nothing I said (silence)"}
    return TripletStats(
        triplets=total,
        with_silence_positive=silence,
        snapshots_used=used,
        labels=label_count,
        per_command=[TripletCount(key=k, name=names[k], triplets=n) for k, n in per_command.most_common()],
        per_member=[
            TripletCount(key=str(who), name=members.get(who, f"member {who}"), triplets=n)
            for who, n in per_member.most_common()
        ],
    )
