"""The scene's inbox: a background thread takes what the app asks of the household's scene
(`backend.scene_requests`) in order and hands each request to the service: re-read the household's data now,
show another robot, or carry out what a member just said. Survives Redis going away."""

import logging
import threading
from collections.abc import Callable
from typing import Any

import redis

from backend import scene_requests

logger = logging.getLogger(__name__)

WAIT_S = 1.0  # how long one wait for a request lasts (the thread checks for a stop in between)
RECONNECT_S = 2.0


class SceneInbox:
    """Calls `handle(request)` for every request to the household's scene until `stopping` is set."""

    def __init__(
        self, household_id: int, handle: Callable[[dict[str, Any]], None], stopping: threading.Event
    ) -> None:
        self.household_id, self.handle, self.stopping = household_id, handle, stopping
        self.error: str | None = None

    def start(self) -> None:
        threading.Thread(target=self._forever, name="scene-inbox", daemon=True).start()

    def _forever(self) -> None:
        while not self.stopping.is_set():
            try:
                request = scene_requests.next_request(self.household_id, WAIT_S)
            except (redis.RedisError, OSError) as error:
                self.error = f"{type(error).__name__}: {error}"
                self.stopping.wait(RECONNECT_S)
                continue
            self.error = None
            if request is not None:
                self._handle(request)

    def _handle(self, request: dict[str, Any]) -> None:
        try:
            self.handle(request)
        except Exception:  # one bad request must not end the inbox
            logger.exception("the scene could not handle %s", request.get("type"))
