"""Pair labels (is / is not) and their history: who answered, changed or removed each one, and when.

Which pair to ask next: `backend.services.pairs`; the triplets the labels yield: `backend.services.triplets`.
"""

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import bindparam, insert, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend import models
from backend.errors import Conflict, Forbidden, NotFound
from backend.schemas import LabelCreate


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
            f"this pair is already answered (label {existing}); whoever answered it, or an admin, can change "
            f"it with PUT /labels/{existing}"
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
    # The pair's lease is kept until it runs out: a member whose next-pair query read the candidates before
    # this commit could otherwise still claim it, and answer it second (409).
    return {"id": label_id, **label}


def check_may_change(label: models.Label, user_id: int, is_admin: bool) -> None:
    """As with clips: an answer is its labeller's to change or undo, or an admin's."""
    if label.labeller_id != user_id and not is_admin:
        raise Forbidden(
            "only the member who gave this answer (or an admin) may change or undo it; "
            "ask them, or a household admin"
        )


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
