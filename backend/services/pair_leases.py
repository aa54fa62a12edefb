"""Pairs recently handed out by `GET /labels/next`, so that members of one household labelling at the same
time are asked different pairs instead of racing for one and getting 409s.

A lease is claimed atomically (taken unless another member holds it) in Redis, which every API process
shares: two requests, in one process or in two, can never both be handed the same pair while the lease
runs. While Redis cannot be reached the leases live in this process (they then hold within it only); a
second answer to one pair is refused with 409 either way, so a lease never decides what is stored.

An answered pair keeps its lease until it runs out (labels.create_label does not release it): a member whose
next-pair query read the candidates just before the answer was committed would otherwise claim it.
"""

import logging
import threading
import time

import redis

from backend.broker import redis_client

LEASE_SECONDS = 60.0  # about how long one person takes to listen, look and answer, with room to spare
REDIS_PREFIX = "varbot:pair-lease:"
_RETRY_REDIS_AFTER_S = 5.0  # while Redis is away, do not wait on it for every pair
_PURGE_EVERY = 1024

Pair = tuple[int, int, int]  # (household id, snapshot id, clip id)
logger = logging.getLogger(__name__)

# Take the lease if nobody holds it or the caller already does; 1 when taken, 0 when another member holds it.
_CLAIM = """
local holder = redis.call('GET', KEYS[1])
if holder and holder ~= ARGV[1] then return 0 end
redis.call('SET', KEYS[1], ARGV[1], 'PX', ARGV[2])
return 1
"""


def _key(pair: Pair) -> str:
    return REDIS_PREFIX + ":".join(map(str, pair))


class LocalLeases:
    """The fallback: one process's leases, claimed under a lock."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self._holders: dict[Pair, tuple[int, float]] = {}  # pair → (user id, expiry on the monotonic clock)
        self._lock = threading.Lock()
        self._claims = 0

    def held_by_another(self, pair: Pair, user_id: int) -> bool:
        holder = self._holders.get(pair)
        return holder is not None and holder[0] != user_id and holder[1] > time.monotonic()

    def claim(self, pair: Pair, user_id: int) -> bool:
        now = time.monotonic()
        with self._lock:
            if self.held_by_another(pair, user_id):
                return False
            self._holders[pair] = (user_id, now + self.seconds)
            self._claims += 1
            if self._claims % _PURGE_EVERY == 0:
                self._holders = {p: h for p, h in self._holders.items() if h[1] > now}
            return True

    def release(self, pair: Pair) -> None:
        with self._lock:
            self._holders.pop(pair, None)

    def clear(self) -> None:
        with self._lock:
            self._holders.clear()


class PairLeases:
    def __init__(self, seconds: float = LEASE_SECONDS) -> None:
        self.seconds = seconds
        self.local = LocalLeases(seconds)
        self._redis_away_until = 0.0

    def _redis(self) -> redis.Redis | None:
        return None if time.monotonic() < self._redis_away_until else redis_client()

    def _redis_failed(self, error: redis.RedisError) -> None:
        if time.monotonic() >= self._redis_away_until:
            logger.warning("pair leases fall back to this process: Redis is not reachable (%s)", error)
        self._redis_away_until = time.monotonic() + _RETRY_REDIS_AFTER_S

    def claim(self, pair: Pair, user_id: int) -> bool:
        """Hands the pair to this member unless another member holds it; True when the member now holds it."""
        client = self._redis()
        if client is not None:
            try:
                claim = client.register_script(_CLAIM)  # EVALSHA: the script is sent once per server
                return bool(claim(keys=[_key(pair)], args=[str(user_id), int(self.seconds * 1000)]))
            except redis.RedisError as error:
                self._redis_failed(error)
        return self.local.claim(pair, user_id)

    def held_by_another(self, pair: Pair, user_id: int) -> bool:
        client = self._redis()
        if client is not None:
            try:
                holder = client.get(_key(pair))
                return holder is not None and holder != str(user_id).encode()
            except redis.RedisError as error:
                self._redis_failed(error)
        return self.local.held_by_another(pair, user_id)

    def release(self, pair: Pair) -> None:
        self.local.release(pair)
        client = self._redis()
        if client is not None:
            try:
                client.delete(_key(pair))
            except redis.RedisError as error:
                self._redis_failed(error)

    def clear(self) -> None:
        """Forget every lease (tests: leases name rows that a rolled-back transaction removed)."""
        self.local.clear()
        self._redis_away_until = 0.0
        try:
            for key in redis_client().scan_iter(f"{REDIS_PREFIX}*"):
                redis_client().delete(key)
        except redis.RedisError as error:
            self._redis_failed(error)


pair_leases = PairLeases()
