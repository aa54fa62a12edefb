"""Passwords (Argon2), session tokens (random, stored only as an HMAC), CSRF tokens, and the short-lived
cache of sign-in lookups.

Each Argon2 hash takes `password_hash_memory_kib` (64 MiB by default) while it runs, so a process hashes at
most `password_hash_concurrency` passwords at once, whatever the sign-in rate: memory stays flat. Sign-ins
wait for a slot on the event loop (not on one of the request threads, which other members' requests need),
and are turned away (`HashingBusy`) when more than `password_hash_queue` are already waiting."""

import asyncio
import hashlib
import hmac
import secrets
import threading
import time
import weakref
from functools import lru_cache
from typing import Any

import anyio
import anyio.to_thread
from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError

from backend.errors import ApiError
from backend.settings import get_settings

SESSION_COOKIE = "varbot_session"
CSRF_COOKIE = "varbot_csrf"
CSRF_HEADER = "X-CSRF-Token"


@lru_cache
def _hasher(time_cost: int, memory_kib: int) -> tuple[PasswordHasher, str]:
    hasher = PasswordHasher(time_cost=time_cost, memory_cost=memory_kib)
    # Verifying against a dummy hash keeps "no such user" as slow as "wrong password".
    return hasher, hasher.hash("not a real password")


def _current_hasher() -> tuple[PasswordHasher, str]:
    settings = get_settings()
    return _hasher(settings.password_hash_time_cost, settings.password_hash_memory_kib)


@lru_cache
def _hash_slots(concurrency: int) -> threading.BoundedSemaphore:
    return threading.BoundedSemaphore(concurrency)


def _slot() -> threading.BoundedSemaphore:
    """Held while one password is hashed: every caller in this process (sign-in, password change, CLI)."""
    return _hash_slots(get_settings().password_hash_concurrency)


def hash_password(password: str) -> str:
    with _slot():
        return _current_hasher()[0].hash(password)


def verify_password(password: str, password_hash: str | None) -> bool:
    hasher, dummy = _current_hasher()
    try:
        with _slot():
            return hasher.verify(password_hash or dummy, password) and password_hash is not None
    except (VerificationError, InvalidHashError):
        return False


def new_token() -> str:
    return secrets.token_urlsafe(32)


def token_digest(token: str, secret_key: str) -> str:
    return hmac.new(secret_key.encode(), token.encode(), hashlib.sha256).hexdigest()


def same_token(a: str, b: str) -> bool:
    return hmac.compare_digest(a.encode(), b.encode())


class SignedInCache:
    """Recent sign-in lookups (token HMAC → who), so that a busy client is not looked up on every request.

    Entries live `ttl_s` seconds. Signing out, a role change, deactivation and a password reset forget the
    affected entries in this process at once (after their commit); a lookup that raced with such a change is
    not kept. Another API process (`--workers N`) or the CLI sees such a change within `ttl_s` at the latest.
    """

    def __init__(self, ttl_s: float = 2.0, max_entries: int = 10_000) -> None:
        self.ttl_s, self.max_entries = ttl_s, max_entries
        self._entries: dict[tuple[str, str], tuple[float, Any]] = {}
        self._lock = threading.Lock()
        self.generation = 0  # bumped by every forget: a lookup that started before one is not remembered

    def get(self, token_hash: str, kind: str) -> Any | None:
        found = self._entries.get((token_hash, kind))
        if found is None or found[0] < time.monotonic():
            return None
        return found[1]

    def remember(self, token_hash: str, kind: str, value: Any, generation: int) -> None:
        with self._lock:
            if generation != self.generation:
                return
            if len(self._entries) >= self.max_entries:
                now = time.monotonic()
                self._entries = {key: entry for key, entry in self._entries.items() if entry[0] >= now}
                while len(self._entries) >= self.max_entries:
                    del self._entries[next(iter(self._entries))]
            self._entries[(token_hash, kind)] = (time.monotonic() + self.ttl_s, value)

    def forget(self, *, user_id: int | None = None, auth_session_id: int | None = None) -> None:
        """Drops the entries of one member (all their sessions) or of one session."""
        with self._lock:
            self.generation += 1
            self._entries = {
                key: entry
                for key, entry in self._entries.items()
                if entry[1].user_id != user_id and entry[1].auth_session_id != auth_session_id
            }

    def clear(self) -> None:
        with self._lock:
            self.generation += 1
            self._entries.clear()


signed_in_cache = SignedInCache()


class HashingBusy(ApiError):
    status_code = 503

    def __init__(self) -> None:
        super().__init__("too many sign-ins are waiting for their password to be checked; try again soon")
        self.headers = {"Retry-After": "1"}


class _WaitingRoom:
    """The sign-ins of one event loop that are having, or waiting for, a hashing slot."""

    def __init__(self, slots: int) -> None:
        self.limiter = anyio.CapacityLimiter(slots)  # belongs to the loop it was made on
        self.inside = 0


_waiting_rooms: "weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, _WaitingRoom]" = (
    weakref.WeakKeyDictionary()
)


def _waiting_room(slots: int) -> _WaitingRoom:
    loop = asyncio.get_running_loop()
    if (room := _waiting_rooms.get(loop)) is None:
        room = _waiting_rooms[loop] = _WaitingRoom(slots)
    return room


async def verify_password_waiting(password: str, password_hash: str | None) -> bool:
    """`verify_password` for sign-ins: waits for a hashing slot without holding a request thread."""
    settings = get_settings()
    room = _waiting_room(settings.password_hash_concurrency)
    if room.inside >= settings.password_hash_concurrency + settings.password_hash_queue:
        raise HashingBusy()
    room.inside += 1
    try:
        return await anyio.to_thread.run_sync(verify_password, password, password_hash, limiter=room.limiter)
    finally:
        room.inside -= 1
