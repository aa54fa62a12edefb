"""A robot task's state in Redis (queued, running, done, refused, failed, with a message saying why): the
API writes it queued, the worker the rest, and the API reads it back for GET …/{task_id}."""

import contextlib
import json
from typing import Any

import redis

from backend import broker
from backend.errors import Unavailable

STATUS_TTL_S = 7 * 24 * 3600


def write_status(key: str, status: dict[str, Any]) -> None:
    """Raises Unavailable when Redis cannot be reached."""
    try:
        broker.redis_client().set(key, json.dumps(status), ex=STATUS_TTL_S)
    except redis.RedisError as exc:
        raise Unavailable(f"the task queue (Redis) is not reachable: {exc}") from exc


def read_status(key: str) -> dict[str, Any] | None:
    try:
        raw = broker.redis_client().get(key)
    except redis.RedisError as exc:
        raise Unavailable(f"the task queue (Redis) is not reachable: {exc}") from exc
    if raw is None:
        return None
    with contextlib.suppress(ValueError):
        return dict(json.loads(raw))
    return None
