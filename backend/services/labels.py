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

import numpy as np
from sqlalchemy import and_, exists, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend import models
from backend.errors import Conflict, NotFound
from backend.schemas import LabelCreate, TripletCount, TripletStats
from backend.services.clips import get_clip
from backend.services.snapshots import get_snapshot

SILENCE = "silence"
_TOP_CANDIDATES = 8  # concurrent labellers of one household get different pairs instead of racing for one


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


def _record(
    session: Session, label: models.Label, action: str, user: models.User, verdict: str | None
) -> None:
    session.add(
        models.LabelEvent(
            household_id=label.household_id,
            label_id=label.id,
            snapshot_id=label.snapshot_id,
            clip_id=label.clip_id,
            action=action,
            verdict=verdict,
            user_id=user.id,
        )
    )


def create_label(session: Session, user: models.User, body: LabelCreate) -> models.Label:
    snapshot = get_snapshot(session, user.household_id, body.snapshot_id, include_deleted=False)
    clip = get_clip(session, user.household_id, body.clip_id, include_deleted=False)
    existing = session.scalar(
        select(models.Label.id).where(
            models.Label.snapshot_id == snapshot.id, models.Label.clip_id == clip.id
        )
    )
    if existing is not None:
        raise Conflict(
            f"this pair is already answered (label {existing}); change it with PUT /labels/{existing}"
        )
    now = datetime.now(UTC)
    label = models.Label(
        household_id=user.household_id,
        snapshot_id=snapshot.id,
        clip_id=clip.id,
        verdict=body.verdict,
        labeller_id=user.id,
        updated_by_id=user.id,
        created_at=now,
        updated_at=now,
    )
    session.add(label)
    try:
        session.flush()
    except IntegrityError as exc:  # answered by someone else a moment ago
        session.rollback()
        raise Conflict("this pair was just answered by someone else; fetch the next pair") from exc
    _record(session, label, "created", user, label.verdict)
    session.commit()
    return label


def change_label(session: Session, label: models.Label, user: models.User, verdict: str) -> models.Label:
    if label.verdict != verdict:
        label.verdict = verdict
        label.updated_at = datetime.now(UTC)
        label.updated_by_id = user.id
        _record(session, label, "changed", user, verdict)
        session.commit()
    return label


def delete_label(session: Session, label: models.Label, user: models.User) -> None:
    _record(session, label, "deleted", user, None)
    session.delete(label)
    session.commit()


# --- which pair next ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PairChoice:
    snapshot: models.Snapshot
    clip: models.Clip
    strategy: str
    informativeness: float | None = None


def _live_snapshots(household_id: int, robot_id: int | None):  # type: ignore[no-untyped-def]
    query = select(models.Snapshot.id).where(
        models.Snapshot.household_id == household_id, models.Snapshot.deleted_at.is_(None)
    )
    return query if robot_id is None else query.where(models.Snapshot.robot_id == robot_id)


def _clips_in_asking_order(session: Session, household_id: int) -> list[models.Clip]:
    """Least-answered command first, and within it the least-answered clip: balanced across commands."""
    clips = list(
        session.scalars(
            select(models.Clip).where(
                models.Clip.household_id == household_id, models.Clip.deleted_at.is_(None)
            )
        )
    )
    counts = dict(
        session.execute(
            select(models.Label.clip_id, func.count())
            .where(models.Label.household_id == household_id)
            .group_by(models.Label.clip_id)
        ).all()
    )
    per_command: Counter[str] = Counter()
    for clip in clips:
        per_command[command_key(clip.id, clip.name)] += counts.get(clip.id, 0)
    random.shuffle(clips)  # ties are broken at random
    return sorted(clips, key=lambda c: (per_command[command_key(c.id, c.name)], counts.get(c.id, 0)))


def next_pair(session: Session, household_id: int, robot_id: int | None) -> PairChoice | None:
    clips = _clips_in_asking_order(session, household_id)
    if not clips:
        return None
    informative = _informative_pair(session, household_id, robot_id, clips)
    if informative is not None:
        return informative
    label_count = (
        select(func.count()).where(models.Label.snapshot_id == models.Snapshot.id).correlate(models.Snapshot)
    ).scalar_subquery()
    for clip in clips:
        # Prefer images already partly answered: asking every command about one image completes its triplets.
        unanswered = _live_snapshots(household_id, robot_id).where(
            ~exists().where(models.Label.snapshot_id == models.Snapshot.id, models.Label.clip_id == clip.id)
        )
        rows = session.execute(
            unanswered.add_columns(label_count)
            .order_by(label_count.desc(), models.Snapshot.id)
            .limit(_TOP_CANDIDATES)
        ).all()
        if rows:
            best = rows[0][1]
            snapshot_id = random.choice([row[0] for row in rows if row[1] == best])
            return PairChoice(session.get_one(models.Snapshot, snapshot_id), clip, "balanced")
    return None


def _informative_pair(
    session: Session, household_id: int, robot_id: int | None, clips: list[models.Clip]
) -> PairChoice | None:
    """Once an active model has embedded the household's data: the unanswered (image, clip) whose image
    sits most nearly between the clip's command cluster and another command's cluster on the sphere."""
    active = select(models.ModelVersion.id, models.ModelVersion.robot_id).where(
        models.ModelVersion.household_id == household_id,
        models.ModelVersion.status == models.ModelStatus.ACTIVE,
    )
    if robot_id is not None:
        active = active.where(models.ModelVersion.robot_id == robot_id)
    for model_id, model_robot_id in session.execute(active).all():
        clip_vectors = dict(
            session.execute(
                select(models.Embedding.clip_id, models.Embedding.vector).where(
                    models.Embedding.model_version_id == model_id, models.Embedding.clip_id.is_not(None)
                )
            ).all()
        )
        groups: dict[str, list[list[float]]] = defaultdict(list)
        for clip in clips:
            if clip.id in clip_vectors:
                groups[command_key(clip.id, clip.name)].append(clip_vectors[clip.id])
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
        best: tuple[float, int, models.Clip] | None = None
        for clip in clips:
            key = command_key(clip.id, clip.name)
            if key not in groups:
                continue
            column = keys.index(key)
            others = np.delete(similarity, column, axis=1).max(axis=1)
            # 1 when the image is as close to this command as to its nearest rival, 0 at opposite poles.
            score = 1.0 - np.abs(similarity[:, column] - others) / 2.0
            for index in np.argsort(-score)[: _TOP_CANDIDATES * 4]:
                if (int(snapshot_ids[index]), clip.id) not in answered:
                    if best is None or score[index] > best[0]:
                        best = (float(score[index]), int(snapshot_ids[index]), clip)
                    break
        if best is not None:
            return PairChoice(session.get_one(models.Snapshot, best[1]), best[2], "informative", best[0])
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
