"""The robot's attempts at the household's commands, and "did it do what I said?".

An attempt is a snapshot (source `attempt`) of the robot's final view after it played its policy on one
recorded command; `meta["attempt"]` names the command (`command`: its key, `clip_id`: the recording it was
given) and the blob keys of a few earlier frames (`frames`, a short replay, the final view last). The robot
worker makes them (`worker.attempts`); the API asks for them (`ask_for_attempts`) and turns each answer into
ordinary is / is-not labels on the final snapshot (`answer_attempt`, the rule is `labels_for_answer`), so
triplets, statistics, history and undo (DELETE /labels/{id}) work as for any other answer.
"""

import math
from collections import defaultdict
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import broker, models
from backend.errors import Conflict, Invalid, NotFound, Unavailable
from backend.services import task_status
from backend.services.pair_leases import pair_leases
from backend.services.snapshots import refund_capture, reserve_capture
from core.labels import Verdict, command_key

ATTEMPT_SOURCE = "attempt"
NOTHING = "nothing"  # the answer "it shows none of our commands"
_CANDIDATES = 40  # unanswered attempts looked at per request


@dataclass(frozen=True)
class Command:
    key: str  # `core.labels.command_key`
    name: str  # what the household calls it
    clip_ids: tuple[int, ...]  # its live recordings


def household_commands(session: Session, household_id: int) -> dict[str, Command]:
    """The household's commands (live clips grouped by `command_key`), ordered by name."""
    rows = session.execute(
        select(models.Clip.id, models.Clip.name)
        .where(models.Clip.household_id == household_id, models.Clip.deleted_at.is_(None))
        .order_by(models.Clip.id)
    ).all()
    clips: defaultdict[str, list[int]] = defaultdict(list)
    names: dict[str, str] = {}
    for clip_id, name in rows:
        key = command_key(clip_id, name)
        clips[key].append(clip_id)
        names.setdefault(key, name.strip() if name and name.strip() else f"clip {clip_id}")
    ordered = sorted(clips, key=lambda key: (names[key].casefold(), key))
    return {key: Command(key, names[key], tuple(clips[key])) for key in ordered}


def commands_with_an_is_answer(session: Session, robot_id: int) -> set[str]:
    """Keys of the commands for which some view of this robot has been answered *is* (live recordings)."""
    rows = session.execute(
        select(models.Clip.id, models.Clip.name)
        .join(models.Label, models.Label.clip_id == models.Clip.id)
        .join(models.Snapshot, models.Snapshot.id == models.Label.snapshot_id)
        .where(
            models.Snapshot.robot_id == robot_id,
            models.Label.verdict == Verdict.IS.value,
            models.Clip.deleted_at.is_(None),
        )
        .distinct()
    ).all()
    return {command_key(clip_id, name) for clip_id, name in rows}


def shown_command(
    commands: dict[str, Command], asked: str, said_yes: bool, instead: str | None
) -> str | None:
    """What an answer about an attempt at command `asked` says its final view shows: a command's key, or
    None for nothing the household said."""
    if asked not in commands:
        raise Invalid("the command this attempt was asked has no recording left; skip it")
    if said_yes:
        return asked
    if instead is None:
        raise Invalid(f"after 'no', say what the view shows instead: another command's key, or {NOTHING!r}")
    if instead == NOTHING:
        return None
    if instead == asked:
        raise Invalid("'no' and then the same command contradict each other: answer 'yes' instead")
    if instead not in commands:
        raise Invalid(f"{instead!r} is none of the household's commands; name one of them, or {NOTHING!r}")
    return instead


def labels_for_answer(commands: dict[str, Command], shown: str | None) -> list[tuple[int, Verdict]]:
    """The is / is-not pairs an answer gives the attempt's final view, from what it says the view shows:

    - *yes, that's it*: *is* for every recording of the asked command, *is not* for every other command's;
    - *no*, it shows command X instead: *is* for X's recordings, *is not* for every other command's (the asked
      one included);
    - *no*, it shows nothing we said: *is not* for every command's recordings, which the triplet rule
      (`core.labels`) turns into silence triplets.

    A view of one target shows one command, so every answer labels the view for every command: a full
    label, never only an *is not*."""
    return [
        (clip_id, Verdict.IS if key == shown else Verdict.IS_NOT)
        for key, command in commands.items()
        for clip_id in command.clip_ids
    ]


def attempt_of(snapshot: models.Snapshot) -> dict[str, Any]:
    attempt = (snapshot.meta or {}).get("attempt")
    if snapshot.source != ATTEMPT_SOURCE or not isinstance(attempt, dict):
        raise NotFound("attempt", snapshot.id)
    return attempt


@dataclass(frozen=True)
class AttemptChoice:
    snapshot: models.Snapshot
    asked: Command
    others: list[Command]


def next_attempt(
    session: Session, user_id: int, household_id: int, robot_id: int | None, skipped: list[int] | None = None
) -> AttemptChoice | None:
    """The oldest unanswered attempt whose command still has a recording and that this member has not
    `skipped`, claimed for them (an attempt another member is judging is passed over, as pairs are); None
    when there is none."""
    commands = household_commands(session, household_id)
    query = select(models.Snapshot).where(
        models.Snapshot.household_id == household_id,
        models.Snapshot.source == ATTEMPT_SOURCE,
        models.Snapshot.deleted_at.is_(None),
        models.Snapshot.label_count == 0,
    )
    if robot_id is not None:
        query = query.where(models.Snapshot.robot_id == robot_id)
    if skipped:
        query = query.where(models.Snapshot.id.not_in(skipped))
    fallback = None
    for snapshot in session.scalars(query.order_by(models.Snapshot.id).limit(_CANDIDATES)):
        asked = commands.get(str((snapshot.meta or {}).get("attempt", {}).get("command")))
        if asked is None:
            continue
        choice = AttemptChoice(snapshot, asked, [c for c in commands.values() if c.key != asked.key])
        if pair_leases.claim(_lease(household_id, snapshot), user_id):
            return choice
        fallback = fallback or choice
    return fallback


@dataclass(frozen=True)
class StoredAnswer:
    shows: str  # the command's name, or NOTHING
    labels: list[models.Label]


def answer_attempt(
    session: Session,
    user_id: int,
    household_id: int,
    snapshot: models.Snapshot,
    said_yes: bool,
    instead: str | None,
) -> StoredAnswer:
    """Stores an answer as labels on the attempt's final snapshot, all in one commit, each with its
    history event; refused with 409 when any of its pairs is already answered."""
    if snapshot.deleted_at is not None:
        raise Conflict(f"attempt {snapshot.id} was deleted; fetch the next one")
    commands = household_commands(session, household_id)
    shown = shown_command(commands, str(attempt_of(snapshot).get("command")), said_yes, instead)
    pairs = labels_for_answer(commands, shown)
    answered = session.scalar(
        select(models.Label.id).where(
            models.Label.snapshot_id == snapshot.id, models.Label.clip_id.in_([c for c, _ in pairs])
        )
    )
    if answered is not None:
        raise Conflict(f"attempt {snapshot.id} is already answered (label {answered}); fetch the next one")
    now = datetime.now(UTC)
    labels = [
        models.Label(
            household_id=household_id, snapshot_id=snapshot.id, clip_id=clip_id, verdict=verdict.value,
            labeller_id=user_id, created_at=now, updated_at=now, updated_by_id=user_id,
        )
        for clip_id, verdict in pairs
    ]  # fmt: skip
    session.add_all(labels)
    session.flush()
    session.add_all(
        models.LabelEvent(
            household_id=household_id, label_id=label.id, snapshot_id=snapshot.id, clip_id=label.clip_id,
            action="created", verdict=label.verdict, user_id=user_id, at=now,
        )
        for label in labels
    )  # fmt: skip
    session.commit()
    # The lease is kept until it runs out, as for pairs (`labels.create_label`): a member whose next-attempt
    # query read the candidates before this commit could otherwise still claim it, and answer it second.
    return StoredAnswer(NOTHING if shown is None else commands[shown].name, labels)


def _lease(household_id: int, snapshot: models.Snapshot) -> tuple[int, int, int]:
    return (household_id, snapshot.id, int((snapshot.meta or {}).get("attempt", {}).get("clip_id") or 0))


def frame_key(snapshot: models.Snapshot, index: int) -> str:
    frames = attempt_of(snapshot).get("frames") or []
    if not 0 <= index < len(frames):
        raise NotFound(f"frame of attempt {snapshot.id}", index)
    return str(frames[index])


# --- asking the robot worker ---------------------------------------------------------------------------


def random_view_count(attempts: int, random_share: float) -> int:
    """How many random-exploration views join `attempts` attempts so that they are `random_share` of all."""
    return math.ceil(attempts * random_share / (1 - random_share)) if random_share > 0 else 0


def check_commands(session: Session, household_id: int, wanted: list[str] | None) -> list[str]:
    """The command keys to attempt: every command of the household, or those named (by name or key)."""
    commands = household_commands(session, household_id)
    if not commands:
        raise Conflict(
            "your household has no recorded commands yet: record some on the Record page, then ask for "
            "attempts"
        )
    if not wanted:
        return list(commands)
    by_word = {c.name.casefold(): c.key for c in commands.values()} | {key: key for key in commands}
    keys: list[str] = []
    missing = []
    for word in wanted:
        key = by_word.get(word) or by_word.get(word.strip().casefold())
        if key is None:
            missing.append(word)
        elif key not in keys:
            keys.append(key)
    if missing:
        known = ", ".join(c.name for c in commands.values())
        raise Invalid(
            f"no recording of {', '.join(map(repr, missing))}: record it on the Record page first "
            f"(recorded: {known})"
        )
    return keys


def ask_for_attempts(
    robot: models.Robot,
    command_keys: list[str],
    attempts: int,
    random_views: int,
    per_hour: int,
    task_id: str,
    seed: int | None = None,
) -> None:
    """Counts the views against the capture quota, records the task as queued and sends it to the robot
    worker (`broker.TASK_TRY_COMMANDS`)."""
    views = attempts + random_views
    reserve_capture(robot.household_id, views, per_hour)
    kwargs = {
        "robot_id": robot.id,
        "household_id": robot.household_id,
        "attempts": attempts,
        "random_views": random_views,
        "commands": command_keys,
        "seed": seed,
    }
    try:
        write_status(task_id, {"state": "queued", "robot_id": robot.id, "message": "waiting for the robot"})
        broker.send_task(broker.TASK_TRY_COMMANDS, kwargs, broker.QUEUE_ROBOT, task_id)
    except (broker.BrokerUnavailable, Unavailable) as exc:
        refund_capture(robot.household_id, views)
        raise Unavailable(f"{exc}; nothing was attempted") from exc


def write_status(task_id: str, status: dict[str, Any]) -> None:
    """An attempts task's state (`backend.services.task_status`); the worker updates it."""
    task_status.write_status(broker.attempts_status_key(task_id), status)


def read_status(task_id: str) -> dict[str, Any] | None:
    return task_status.read_status(broker.attempts_status_key(task_id))
