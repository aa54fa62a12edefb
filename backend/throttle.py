"""The sign-in throttle: wrong passwords are counted per account and per client address over a sliding window
(`login_window_seconds`); beyond `login_failures_per_account` / `_per_address` a sign-in is refused with 429
and `Retry-After`, before any password is hashed. Refused attempts do not count, so the owner's right
password works again once the window has passed; a successful sign-in does not count either.

The counts live in Redis, which every API process shares; while Redis cannot be reached, in the database
(`login_failures`), which they share too. An attempt is recorded *before* its password is checked, so that
forty guesses arriving at once cannot all slip under the limit."""

import contextlib
import hashlib
import math
import time
import uuid
from dataclasses import dataclass, field
from typing import Protocol

import redis
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from backend import models
from backend.broker import redis_client
from backend.errors import ApiError
from backend.settings import Settings

REDIS_PREFIX = "varbot:login:"


class Throttled(ApiError):
    status_code = 429

    def __init__(self, retry_after_s: int) -> None:
        super().__init__(
            f"too many wrong passwords for this account or from this address; try again in {retry_after_s} s"
        )
        self.headers = {"Retry-After": str(retry_after_s)}


def account_key(username: str) -> str:
    # Hashed: the token endpoint's form does not bound the username's length.
    return "account:" + hashlib.sha256(username.strip().lower().encode()).hexdigest()


def address_key(address: str) -> str:
    return "address:" + address[:64]


class Counts(Protocol):
    def add(self, key: str, now: float, window_s: float) -> tuple[str, int, float]:
        """Records one attempt under `key`: its entry, the attempts in the window, the oldest one's time."""
        ...

    def remove(self, entries: dict[str, str]) -> None: ...


class RedisCounts:
    """A sorted set per key, scored by Unix time; it expires with the window."""

    def add(self, key: str, now: float, window_s: float) -> tuple[str, int, float]:
        name, entry = REDIS_PREFIX + key, uuid.uuid4().hex
        pipe = redis_client().pipeline(transaction=True)
        pipe.zremrangebyscore(name, 0, now - window_s)
        pipe.zadd(name, {entry: now})
        pipe.zcard(name)
        pipe.zrange(name, 0, 0, withscores=True)
        pipe.expire(name, math.ceil(window_s))
        _, _, count, oldest, _ = pipe.execute()
        return entry, count, oldest[0][1]

    def remove(self, entries: dict[str, str]) -> None:
        pipe = redis_client().pipeline(transaction=False)
        for key, entry in entries.items():
            pipe.zrem(REDIS_PREFIX + key, entry)
        pipe.execute()


class DatabaseCounts:
    """Rows of `login_failures`; a key's expired rows are dropped whenever it is counted."""

    def __init__(self, session: Session) -> None:
        self.session = session

    def add(self, key: str, now: float, window_s: float) -> tuple[str, int, float]:
        failure = models.LoginFailure(key=key, at=now)
        self.session.add(failure)
        failures = models.LoginFailure
        self.session.execute(delete(failures).where(failures.key == key, failures.at < now - window_s))
        self.session.flush()
        count, oldest = self.session.execute(
            select(func.count(), func.min(failures.at)).where(failures.key == key)
        ).one()
        self.session.commit()
        return str(failure.id), count, oldest

    def remove(self, entries: dict[str, str]) -> None:
        ids = [int(entry) for entry in entries.values()]
        self.session.execute(delete(models.LoginFailure).where(models.LoginFailure.id.in_(ids)))
        self.session.commit()


@dataclass
class Attempt:
    """One sign-in attempt, counted under each of its keys until it is forgiven."""

    counts: Counts
    entries: dict[str, str] = field(default_factory=dict)  # key -> this attempt's entry under it


def _count(counts: Counts, limits: dict[str, int], window_s: float) -> Attempt:
    attempt, now, waits = Attempt(counts), time.time(), []
    for key, limit in limits.items():
        entry, count, oldest = counts.add(key, now, window_s)
        attempt.entries[key] = entry
        if count > limit:
            waits.append(oldest + window_s - now)
    if waits:
        forgive(attempt)
        raise Throttled(max(1, math.ceil(max(waits))))
    return attempt


def begin(session: Session, settings: Settings, username: str, address: str) -> Attempt:
    """Counts a sign-in attempt under its account and address; `Throttled` when either is over its limit."""
    limits = {
        account_key(username): settings.login_failures_per_account,
        address_key(address): settings.login_failures_per_address,
    }
    try:
        return _count(RedisCounts(), limits, settings.login_window_seconds)
    except redis.RedisError:
        return _count(DatabaseCounts(session), limits, settings.login_window_seconds)


def forgive(attempt: Attempt) -> None:
    """Takes back an attempt that was not a wrong password (it succeeded, or it was refused unchecked)."""
    with contextlib.suppress(redis.RedisError):  # Redis went away: its entries expire with the window
        attempt.counts.remove(attempt.entries)
    attempt.entries.clear()
