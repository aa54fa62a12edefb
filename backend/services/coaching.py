"""Coaching the robot by voice: a short self-improvement session on the robot worker (`worker.coaching`)
while a member watches the scene and says the command when the robot is where it should be.

A session lives in Redis (it is as short as a person's attention, and what it leaves behind is ordinary rows):
- `status`: JSON the worker keeps current (state, step, message);
- `frames`: the frames on show, a sorted set scored by the time each appeared, written by the worker;
- `clips`: the member's clips in the order they came (clip id and when it was said, on the API's clock),
  read by the worker as the current sound S_t of the frames they overlap;
- `cancel`: set when a member asks the session to stop.

Each clip the API receives is stored at once as an ordinary recording of the command, the frame it was said
over as a snapshot (source `coaching`) and an *is* label on the pair, in the database: a session that dies
loses nothing already said. The learner's clock and the API's are both `time.time()` of machines assumed in
sync; the browser's clock is never trusted (its times are shifted by how far its "sent at" is from the API's
"received at")."""

import base64
import binascii
import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import redis
from sqlalchemy.orm import Session

from backend import broker, models
from backend.blobs import BlobStore
from backend.errors import Conflict, Invalid, NotFound, Unavailable
from backend.schemas import LabelCreate
from backend.services import labels
from backend.services.attempts import Command, household_commands
from backend.services.snapshots import create_snapshot
from core.labels import Verdict

COACHING_SOURCE = "coaching"
TTL_S = 3600  # a session's keys outlive it by an hour (its status can still be read)
FRAMES_KEPT_S = 120.0  # a clip arriving later than this after it was said finds no frame
MAX_CLIP_SPAN_S = 15.0
MIN_SECONDS, MAX_SECONDS = 20, 600
ACTIVE_STATES = ("queued", "running", "cancelling")


def key(session_id: str, part: str) -> str:
    """Redis key of one part of a session: status, frames, clips, cancel, labels."""
    return f"varbot:coaching:{session_id}:{part}"


def _redis() -> redis.Redis:
    return broker.redis_client()


def _unreachable(exc: Exception) -> Unavailable:
    return Unavailable(f"the task queue (Redis) is not reachable: {exc}")


# --- the session's state -----------------------------------------------------------------------------------


def write_status(session_id: str, status: dict[str, Any]) -> None:
    """The worker's (and, when queued or refused, the API's) account of the session."""
    try:
        _redis().set(key(session_id, "status"), json.dumps(status), ex=TTL_S)
    except redis.RedisError as exc:
        raise _unreachable(exc) from exc


def read_status(session_id: str) -> dict[str, Any] | None:
    try:
        raw = _redis().get(key(session_id, "status"))
        answered = int(_redis().get(key(session_id, "labels")) or 0)
    except redis.RedisError as exc:
        raise _unreachable(exc) from exc
    if raw is None:
        return None
    with contextlib.suppress(ValueError):
        return {**json.loads(raw), "labels": answered}
    return None


def session_of(session_id: str, robot: models.Robot) -> dict[str, Any]:
    status = read_status(session_id)
    if status is None or status.get("robot_id") != robot.id:
        raise NotFound("coaching session", session_id)
    return status


def ask_to_stop(session_id: str) -> None:
    try:
        _redis().set(key(session_id, "cancel"), "1", ex=TTL_S)
    except redis.RedisError as exc:
        raise _unreachable(exc) from exc


def stop_asked(session_id: str) -> bool:
    """For the worker: best effort, a Redis hiccup is not a cancel."""
    try:
        return bool(_redis().exists(key(session_id, "cancel")))
    except redis.RedisError:
        return False


def command_to_coach(session: Session, household_id: int, word: str) -> Command:
    commands = household_commands(session, household_id)
    if not commands:
        raise Conflict("your household has no recorded commands yet: record one on the Record page first")
    by_word = {c.name.casefold(): c for c in commands.values()} | commands
    found = by_word.get(word) or by_word.get(word.strip().casefold())
    if found is None:
        known = ", ".join(f"“{c.name}”" for c in commands.values())
        raise Invalid(f"“{word}” is none of your household's commands; coach one of these: {known}")
    return found


def start_session(
    robot: models.Robot, command: Command, user_id: int, seconds: int, steps_per_s: float, session_id: str
) -> None:
    """Records the session as queued and sends it to the robot worker (`broker.TASK_COACH`)."""
    status = {
        "state": "queued", "robot_id": robot.id, "household_id": robot.household_id, "user_id": user_id,
        "command": command.key, "command_name": command.name, "step": 0,
        "steps": int(seconds * steps_per_s), "steps_per_s": steps_per_s, "voiced_steps": 0,
        "message": "waiting for the robot (it finishes what it is doing first)",
    }  # fmt: skip
    kwargs = {
        "session_id": session_id, "robot_id": robot.id, "household_id": robot.household_id,
        "command": command.key, "seconds": seconds, "steps_per_s": steps_per_s,
    }  # fmt: skip
    write_status(session_id, status)
    try:
        broker.send_task(broker.TASK_COACH, kwargs, broker.QUEUE_ROBOT, session_id)
    except broker.BrokerUnavailable as exc:
        raise Unavailable(f"{exc}; no coaching session was started") from exc


# --- frames (the worker writes them) -----------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    step: int
    shown_from: float
    shown_to: float
    png: bytes
    state: list[float]
    sim_heard: int | None  # the simulator's account, for scoring only (None on a real robot)


def add_frame(session_id: str, frame: Frame) -> None:
    """Keeps the frame on show (and the last FRAMES_KEPT_S seconds of them) for clips to find."""
    member = json.dumps(
        {
            "step": frame.step, "from": frame.shown_from, "to": frame.shown_to,
            "png": base64.b64encode(frame.png).decode("ascii"), "state": frame.state,
            "sim_heard": frame.sim_heard,
        }
    )  # fmt: skip
    frames = key(session_id, "frames")
    pipe = _redis().pipeline()
    pipe.zadd(frames, {member: frame.shown_from})
    pipe.zremrangebyscore(frames, "-inf", frame.shown_from - FRAMES_KEPT_S)
    pipe.expire(frames, TTL_S)
    pipe.execute()


def frame_said_over(session_id: str, said_from: float, said_to: float) -> Frame | None:
    """The frame on show at the middle of the clip, or else the last one on show while it was said."""
    try:
        raw = _redis().zrangebyscore(key(session_id, "frames"), said_from - 60.0, said_to)
    except redis.RedisError as exc:
        raise _unreachable(exc) from exc
    frames = [_frame(item) for item in raw]
    # a frame stays on show until the next one appears (the robot pauses while it learns between updates)
    ends = [later.shown_from for later in frames[1:]] + [float("inf")]
    shown = [(f, max(f.shown_to, end)) for f, end in zip(frames, ends, strict=False)]
    middle = (said_from + said_to) / 2
    during = [f for f, to in shown if f.shown_from < said_to and said_from < to]
    at_middle = [f for f, to in shown if f.shown_from <= middle < to]
    return (at_middle or during or [None])[-1]


def _frame(raw: bytes | str) -> Frame:
    item = json.loads(raw)
    try:
        png = base64.b64decode(item["png"], validate=True)
    except binascii.Error as exc:
        raise ValueError("a coaching frame's image is not base64") from exc
    return Frame(
        int(item["step"]), float(item["from"]), float(item["to"]), png, item["state"], item["sim_heard"]
    )


# --- clips (the member's voice) ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SpokenTimes:
    """When a clip was said, on the API's clock."""

    said_from: float
    said_to: float


def spoken_times(
    said_from_ms: float, said_to_ms: float, sent_at_ms: float, received_at: float
) -> SpokenTimes:
    """The browser's times moved onto the API's clock: its `sent_at` is taken to be when the API received it
    (the upload's own delay is left in, a few milliseconds on a home network)."""
    if not said_from_ms < said_to_ms <= sent_at_ms + 1000:
        raise Invalid(
            "the clip's times do not fit: said_from_ms < said_to_ms <= sent_at_ms (milliseconds of the "
            "browser's clock, Date.now())"
        )
    if said_to_ms - said_from_ms > MAX_CLIP_SPAN_S * 1000:
        raise Invalid(f"a coaching clip may last at most {MAX_CLIP_SPAN_S:.0f} s: let go of Space sooner")
    shift = received_at - sent_at_ms / 1000
    return SpokenTimes(said_from_ms / 1000 + shift, said_to_ms / 1000 + shift)


@dataclass(frozen=True)
class CoachedAnswer:
    clip: models.Clip
    snapshot: models.Snapshot
    label_id: int
    step: int


def take_clip(
    session: Session,
    blobs: BlobStore,
    robot: models.Robot,
    session_id: str,
    status: dict[str, Any],
    said: SpokenTimes,
    store_clip: Callable[[], models.Clip],
) -> CoachedAnswer:
    """Stores a member's clip said during a session: the frame it was said over becomes a snapshot with an
    *is* label for the clip (stored by `store_clip()`, a recording of the coached command), and the clip is
    handed to the worker as the current sound of the frames it overlaps."""
    if status.get("state") not in ("running", "cancelling"):
        raise Conflict(_not_running(status))
    frame = frame_said_over(session_id, said.said_from, said.said_to)
    if frame is None:
        raise Conflict(
            "the robot was not moving while you spoke (no view of it from then is kept): hold Space while "
            "the robot works in the scene, and let go after saying the command"
        )
    clip = store_clip()
    meta = {
        "coaching": {"session_id": session_id, "step": frame.step, "clip_id": clip.id,
                     "command": status.get("command")},
        "sim_heard": frame.sim_heard,
    }  # fmt: skip
    snapshot = create_snapshot(session, blobs, robot, frame.png, frame.state, COACHING_SOURCE, meta)
    label = labels.create_label(
        session, clip.speaker_id, robot.household_id,
        LabelCreate(snapshot_id=snapshot.id, clip_id=clip.id, verdict=Verdict.IS),
    )  # fmt: skip
    heard = {"clip_id": clip.id, "said_from": said.said_from, "said_to": said.said_to}
    try:
        pipe = _redis().pipeline()
        pipe.rpush(key(session_id, "clips"), json.dumps(heard))
        pipe.expire(key(session_id, "clips"), TTL_S)
        pipe.incr(key(session_id, "labels"))
        pipe.expire(key(session_id, "labels"), TTL_S)
        pipe.execute()
    except redis.RedisError as exc:
        raise Unavailable(f"your answer was saved, but the robot could not be told: {exc}") from exc
    return CoachedAnswer(clip, snapshot, int(label["id"]), frame.step)


def _not_running(status: dict[str, Any]) -> str:
    state = status.get("state")
    if state == "queued":
        return "the robot has not started yet: wait until it moves in the scene, then speak"
    return f"this coaching session is over ({state}): start a new one to go on coaching"


def clips_since(session_id: str, seen: int) -> list[dict[str, Any]]:
    """For the worker: the clips after the first `seen`, oldest first (best effort: [] when Redis is away)."""
    try:
        raw = _redis().lrange(key(session_id, "clips"), seen, -1)
    except redis.RedisError:
        return []
    return [json.loads(item) for item in raw]


def received_now() -> float:
    return time.time()
