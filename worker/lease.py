"""Who is working on a run right now: a Redis key with a short expiry, refreshed by a heartbeat thread.

A run is RUNNING in the database from its first start until it ends. Its lease says whether a live worker
holds it: a worker killed with SIGKILL stops refreshing, the lease expires within `LEASE_S`, and the janitor
of any training worker sends the run again; the task resumes from the run's checkpoints.
"""

import logging
import os
import socket
import threading
import time
import uuid

import redis
from sqlalchemy import select

from backend import broker, models
from backend.db import get_session_factory
from backend.services.runs import run_queue

logger = logging.getLogger(__name__)

LEASE_S = float(os.environ.get("VARBOT_RUN_LEASE_S", 30))


def lease_key(run_id: int) -> str:
    return f"varbot:run-lease:{run_id}"


def _requeued_key(run_id: int) -> str:
    return f"varbot:run-requeued:{run_id}"


class RunLease:
    """Hold the lease of one run while the block runs; a daemon thread refreshes it."""

    def __init__(self, run_id: int, client: redis.Redis | None = None) -> None:
        self.run_id = run_id
        self.client = client or broker.redis_client()
        self.token = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def try_acquire(self) -> bool:
        return bool(self.client.set(lease_key(self.run_id), self.token, nx=True, px=int(LEASE_S * 1000)))

    def acquire(self, wait_s: float, still_wanted) -> bool:  # type: ignore[no-untyped-def]
        """Wait up to `wait_s` for a dead holder's lease to expire; give up early when `still_wanted()` is
        False (the run ended meanwhile)."""
        deadline = time.monotonic() + wait_s
        while True:
            if self.try_acquire():
                self._start_heartbeat()
                return True
            if time.monotonic() >= deadline or not still_wanted():
                return False
            time.sleep(min(1.0, LEASE_S / 10))

    def _start_heartbeat(self) -> None:
        def beat() -> None:
            while not self._stop.wait(LEASE_S / 3):
                try:
                    if self.client.get(lease_key(self.run_id)) == self.token.encode():
                        self.client.pexpire(lease_key(self.run_id), int(LEASE_S * 1000))
                    else:
                        self.client.set(lease_key(self.run_id), self.token, nx=True, px=int(LEASE_S * 1000))
                except redis.RedisError:
                    logger.warning("could not refresh the lease of run %s", self.run_id)

        self._thread = threading.Thread(target=beat, name=f"lease-{self.run_id}", daemon=True)
        self._thread.start()

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        try:
            if self.client.get(lease_key(self.run_id)) == self.token.encode():
                self.client.delete(lease_key(self.run_id))
        except redis.RedisError:
            pass  # it expires by itself


def requeue_orphaned_runs() -> list[int]:
    """Send again every RUNNING run that no live worker holds (its worker was killed), to the queue its robot
    runs on (a real arm: the robot queue). Returns their ids."""
    client = broker.redis_client()
    sent = []
    with get_session_factory()() as session:
        rows = session.execute(
            select(models.Run.id, models.Run.kind, models.Robot.kind)
            .join(models.Robot, models.Robot.id == models.Run.robot_id)
            .where(models.Run.status == models.RunStatus.RUNNING)
        ).all()
    for run_id, kind, robot_kind in rows:
        if client.exists(lease_key(run_id)):
            continue
        # One re-send per lease period across all training workers.
        if not client.set(_requeued_key(run_id), "1", nx=True, px=int(LEASE_S * 2000)):
            continue
        task = broker.RUN_TASKS[models.RunKind(kind)]
        broker.send_task(
            task, {"run_id": run_id}, run_queue(robot_kind), f"resume-{run_id}-{uuid.uuid4().hex}"
        )
        logger.warning("run %s was RUNNING without a live worker: sent again to resume it", run_id)
        sent.append(run_id)
    return sent
