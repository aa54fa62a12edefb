"""Pairs recently handed out by `GET /labels/next`, so that members of one household labelling at the same
time are asked different pairs instead of racing for one and getting 409s.

The registry lives in the API process. With several API processes two members can still be handed the same
pair; the second answer is then refused with 409 as before, so a lease is an optimisation, never a lock.
"""

import threading
import time

LEASE_SECONDS = 60.0  # about how long one person takes to listen, look and answer, with room to spare
_PURGE_EVERY = 1024

Pair = tuple[int, int, int]  # (household id, snapshot id, clip id)


class PairLeases:
    def __init__(self, seconds: float = LEASE_SECONDS) -> None:
        self.seconds = seconds
        self._holders: dict[Pair, tuple[int, float]] = {}  # pair → (user id, expiry on the monotonic clock)
        self._lock = threading.Lock()
        self._grants = 0

    def held_by_another(self, pair: Pair, user_id: int) -> bool:
        holder = self._holders.get(pair)
        return holder is not None and holder[0] != user_id and holder[1] > time.monotonic()

    def grant(self, pair: Pair, user_id: int) -> None:
        now = time.monotonic()
        with self._lock:
            self._holders[pair] = (user_id, now + self.seconds)
            self._grants += 1
            if self._grants % _PURGE_EVERY == 0:
                self._holders = {p: h for p, h in self._holders.items() if h[1] > now}

    def release(self, pair: Pair) -> None:
        with self._lock:
            self._holders.pop(pair, None)

    def clear(self) -> None:
        with self._lock:
            self._holders.clear()


pair_leases = PairLeases()
