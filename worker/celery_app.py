"""The Celery application of the workers, configured from `backend.settings`.

Queues (names and task names are the contract in `backend/broker.py`):
- `training`: one task at a time per worker (`--concurrency 1 --prefetch-multiplier 1`), a fresh child process
  per task (`--max-tasks-per-child 1`, set by `varbot worker --queue training`);
- `robot`: snapshot capture, next to the robot.

Celery facts this file answers: `revoke` does not stop a running task (runs stop through their cancel flag);
with Redis, an unacknowledged task is delivered again after `visibility_timeout`, which is set above the
longest run; and a worker killed mid-run leaves its run RUNNING without a lease, which the janitor step of a
training worker notices and sends again (the task resumes from its checkpoints).
"""

import logging
import os
from pathlib import Path
from typing import ClassVar

from celery import Celery, bootsteps, signals

from backend import broker
from backend.settings import get_settings

logger = logging.getLogger(__name__)


def _seconds(name: str, default: float) -> float:
    return float(os.environ.get(name, default))


# A run longer than this is stopped (soft limit: the task fails cleanly and keeps its checkpoints).
TRAINING_SOFT_LIMIT_S = _seconds("VARBOT_TRAINING_TIME_LIMIT_S", 8 * 3600)
TRAINING_HARD_LIMIT_S = TRAINING_SOFT_LIMIT_S + 600
CAPTURE_SOFT_LIMIT_S = _seconds("VARBOT_CAPTURE_TIME_LIMIT_S", 1800)
CAPTURE_HARD_LIMIT_S = CAPTURE_SOFT_LIMIT_S + 60
# Redis re-delivers an unacknowledged task after this long: it must exceed the longest possible run.
VISIBILITY_TIMEOUT_S = TRAINING_HARD_LIMIT_S + 3600
JANITOR_INTERVAL_S = _seconds("VARBOT_RUN_JANITOR_INTERVAL_S", 10)
READY_FILE_ENV = "VARBOT_WORKER_READY_FILE"

TASK_ROUTES = {  # defaults: a run sent with its robot's queue (backend.services.runs.run_queue) keeps it
    broker.TASK_CAPTURE_SNAPSHOTS: {"queue": broker.QUEUE_ROBOT},
    **{name: {"queue": broker.QUEUE_TRAINING} for name in broker.RUN_TASKS.values()},
}


def make_app() -> Celery:
    settings = get_settings()
    celery = Celery("varbot", broker=settings.celery_broker_url, include=["worker.tasks"])
    celery.conf.update(
        task_serializer="json",
        accept_content=["json"],
        task_ignore_result=True,
        task_routes=TASK_ROUTES,
        task_default_queue=broker.QUEUE_TRAINING,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        worker_cancel_long_running_tasks_on_connection_loss=True,
        broker_connection_retry_on_startup=True,
        broker_transport_options={"visibility_timeout": VISIBILITY_TIMEOUT_S},
        worker_hijack_root_logger=False,
        worker_redirect_stdouts=False,
    )
    celery.steps["worker"].add(RunJanitor)
    return celery


class RunJanitor(bootsteps.StartStopStep):
    """On training and robot workers (a real arm's runs run on the robot worker): every few seconds, send
    again any RUNNING run whose worker died (no lease).

    Runs on the worker's own timer in the main process (no extra thread), so a killed worker's run is
    picked up by the next training worker within seconds instead of after the visibility timeout.
    """

    requires: ClassVar[set[str]] = {"celery.worker.components:Timer"}

    def __init__(self, worker, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(worker, **kwargs)
        self.timer_ref = None

    def start(self, worker) -> None:  # type: ignore[no-untyped-def]
        queues = set(worker.app.amqp.queues.consume_from or {}) or {broker.QUEUE_TRAINING}
        if not queues & {broker.QUEUE_TRAINING, broker.QUEUE_ROBOT}:
            return
        from worker.lease import requeue_orphaned_runs

        def scan() -> None:
            try:
                requeue_orphaned_runs()
            except Exception:  # the janitor must never take the worker down
                logger.exception("scanning for orphaned runs failed")

        scan()
        self.timer_ref = worker.timer.call_repeatedly(JANITOR_INTERVAL_S, scan, priority=10)

    def stop(self, worker) -> None:  # type: ignore[no-untyped-def]
        if self.timer_ref is not None:
            self.timer_ref.cancel()
            self.timer_ref = None


@signals.worker_process_init.connect
def _prepare_pool_child(**_kwargs: object) -> None:
    """A forked pool child must not share the parent's database connections, and it must be allowed to
    start processes of its own: PPO and the evaluation step their environments in subprocesses, which
    `multiprocessing` refuses to a daemonic process. The child is still ended with its worker (and, for
    training, after every task), and the environment processes end when their pipes close."""
    import multiprocessing.process

    from backend.db import get_engine

    get_engine().dispose(close=False)
    # billiard marks its pool child daemonic and gives it an authkey the standard library cannot pass on to a
    # forkserver; to `multiprocessing` this child is a main process of its own.
    me = multiprocessing.process.current_process()
    me._config["daemon"] = False  # type: ignore[attr-defined]
    me._config["authkey"] = multiprocessing.process.AuthenticationString(os.urandom(32))  # type: ignore[attr-defined]


@signals.worker_ready.connect
def _announce_ready(**_kwargs: object) -> None:
    """`varbot up` waits for this file to know the worker is consuming."""
    path = os.environ.get(READY_FILE_ENV)
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(str(os.getpid()))


app = make_app()
