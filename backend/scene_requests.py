"""What the app asks of a household's scene, through Redis (the contract between the API, the workers and
`scene/inbox.py`): one list per household, `scene_inbox_key`, that the household's scene takes requests
from in order, and one key per "try it now", `try_status_key`, that the scene writes its progress to and the
Record and Scene pages read back through the API. A list rather than pub/sub: a request made while the scene
is still starting waits for it. Requests (JSON):

- `{"type": "refresh"}`: re-read the household's data now (a model version was activated or rolled back);
- `{"type": "show_robot", "robot_id"}`: show this robot of the household;
- `{"type": "try", "try_id", "robot_id" (or null), "wav_b64" (16 kHz mono WAV), "at" (Unix time)}`: the
  robot carries out what a member just said; the clip is not kept anywhere else.

A try's status (JSON): `{"household_id", "state": starting | running | done | refused | failed, "message"
(in the household's words), "step", "steps", "at"}`. This module imports no Viser, torch or PyBullet."""

import base64
import contextlib
import json
import time
import uuid
from typing import Any, Literal

import redis

from backend import broker

INBOX_TTL_S = 120  # requests nobody took (no scene came up) are dropped after this
TRY_STATUS_TTL_S = 900
TRY_STALE_S = 90.0  # a try the scene takes later than this is refused as too old: the person has moved on
TryState = Literal["starting", "running", "done", "refused", "failed"]
FINISHED: tuple[TryState, ...] = ("done", "refused", "failed")
STARTING_MESSAGE = "Starting… the robot will carry out what you said."


class SceneUnreachable(RuntimeError):
    """Redis, through which the scene is asked, is not reachable."""


def scene_inbox_key(household_id: int) -> str:
    return f"varbot:scene:{household_id}:inbox"


def try_status_key(try_id: str) -> str:
    return f"varbot:scene-try:{try_id}"


def shown_robot_key(household_id: int) -> str:
    """The robot the household's scene shows now (written by the scene, read by the Scene page)."""
    return f"varbot:scene:{household_id}:robot"


def ask(household_id: int, request: dict[str, Any]) -> None:
    """Put `request` in the household's scene inbox; raises SceneUnreachable without Redis."""
    key = scene_inbox_key(household_id)
    try:
        client = broker.redis_client()
        client.rpush(key, json.dumps(request))
        client.expire(key, INBOX_TTL_S)
    except (redis.RedisError, OSError) as error:
        raise SceneUnreachable(f"the scene cannot be reached (Redis: {error})") from error


def ask_to_refresh(household_id: int) -> None:
    """Best effort: the scene also re-reads the household's data every few seconds on its own."""
    with contextlib.suppress(SceneUnreachable):
        ask(household_id, {"type": "refresh"})


def ask_to_try(household_id: int, robot_id: int | None, wav: bytes, message: str = STARTING_MESSAGE) -> str:
    """Queue a "try it now" for the household's scene and write its first status (`message`); its id."""
    try_id = uuid.uuid4().hex
    write_try(try_id, household_id, "starting", message)
    ask(
        household_id,
        {
            "type": "try",
            "try_id": try_id,
            "robot_id": robot_id,
            "wav_b64": base64.b64encode(wav).decode("ascii"),
            "at": time.time(),
        },
    )
    return try_id


def next_request(household_id: int, timeout_s: float) -> dict[str, Any] | None:
    """The scene's next request, waiting at most `timeout_s` (a whole number of seconds, at least 1)."""
    found = broker.redis_client().blpop([scene_inbox_key(household_id)], timeout=max(1, int(timeout_s)))
    if found is None:
        return None
    try:
        request = json.loads(found[1])
    except ValueError:
        return None
    return request if isinstance(request, dict) else None


def write_try(
    try_id: str, household_id: int, state: TryState, message: str, step: int = 0, steps: int = 0
) -> None:
    status = {
        "household_id": household_id,
        "state": state,
        "message": message,
        "step": step,
        "steps": steps,
        "at": time.time(),
    }
    try:
        broker.redis_client().set(try_status_key(try_id), json.dumps(status), ex=TRY_STATUS_TTL_S)
    except (redis.RedisError, OSError) as error:
        raise SceneUnreachable(f"the scene cannot be reached (Redis: {error})") from error


def read_try(try_id: str, household_id: int) -> dict[str, Any] | None:
    """The try's status; None when unknown, expired or another household's."""
    try:
        raw = broker.redis_client().get(try_status_key(try_id))
    except (redis.RedisError, OSError) as error:
        raise SceneUnreachable(f"the scene cannot be reached (Redis: {error})") from error
    status = json.loads(raw) if raw else None
    if not isinstance(status, dict) or status.get("household_id") != household_id:
        return None
    return status


def write_shown_robot(household_id: int, robot_id: int | None) -> None:
    """Best effort: without it the Scene page's choice shows the default robot."""
    key = shown_robot_key(household_id)
    try:
        if robot_id is None:
            broker.redis_client().delete(key)
        else:
            broker.redis_client().set(key, str(robot_id), ex=INBOX_TTL_S * 10)
    except (redis.RedisError, OSError):
        pass


def read_shown_robot(household_id: int) -> int | None:
    try:
        raw = broker.redis_client().get(shown_robot_key(household_id))
    except (redis.RedisError, OSError):
        return None
    return int(raw) if raw else None
