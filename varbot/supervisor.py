"""Keeps a started stack alive: a child that dies is restarted after a pause that doubles with each death in
a row (1 s, 2 s, 4 s … at most 30 s; back to the first pause once it has run a minute), and every death,
restart and return is said on the launcher's output. Nothing else is stopped meanwhile: the API keeps
answering, with 503 and a plain reason only where a request needs the missing part (e.g. Redis)."""

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

from varbot.services import Service, Stack

FIRST_DELAY_S = float(os.environ.get("VARBOT_UP_RESTART_DELAY_S", 1.0))
MAX_DELAY_S = 30.0
STABLE_AFTER_S = 60.0  # running this long after a restart resets the pause
TICK_S = 0.25


@dataclass
class Watched:
    service: Service
    started_at: float
    deaths_in_a_row: int = 0
    restarts: int = 0
    down_since: float | None = None
    restart_at: float | None = None
    coming_back: bool = False


class Supervisor:
    def __init__(self, stack: Stack, say: Callable[[str], None] | None = None) -> None:
        now = time.monotonic()
        self.stack = stack
        self.watched = [Watched(service, now) for service in stack.services]
        self.say = say or (lambda line: print(f"varbot up: {line}", file=sys.stderr, flush=True))

    def run(self, stop_requested: Callable[[], bool]) -> None:
        while not stop_requested():
            self.tick(time.monotonic())
            time.sleep(TICK_S)

    def tick(self, now: float) -> None:
        for watched in self.watched:
            service = watched.service
            if watched.restart_at is None and not service.running:
                self._noticed_death(watched, now)
            elif watched.restart_at is not None and now >= watched.restart_at:
                self._restart(watched, now)
            elif watched.coming_back and service.is_ready():
                watched.coming_back = False
                down_s = now - (watched.down_since or now)
                self.say(f"{service.name} is back, {down_s:.1f} s after it stopped")

    def _noticed_death(self, watched: Watched, now: float) -> None:
        service = watched.service
        code = service.process.returncode if service.process else None
        service.kill_leftovers()  # e.g. a killed Celery worker's pool child, still holding a task
        if now - watched.started_at >= STABLE_AFTER_S:
            watched.deaths_in_a_row = 0
        delay = min(MAX_DELAY_S, FIRST_DELAY_S * 2**watched.deaths_in_a_row)
        watched.deaths_in_a_row += 1
        watched.down_since, watched.restart_at, watched.coming_back = now, now + delay, False
        self.say(
            f"{service.name} stopped unexpectedly (exit code {code}); restarting it in {delay:.0f} s; "
            f"see {service.log_path(self.stack.log_dir)}"
        )

    def _restart(self, watched: Watched, now: float) -> None:
        watched.restarts += 1
        watched.restart_at, watched.started_at, watched.coming_back = None, now, True
        watched.service.start(self.stack.log_dir, self.stack.env)
        self.say(f"{watched.service.name} restarted (restart {watched.restarts})")
