"""Live rollouts: environment 0 of a run's PPO training, published about 10 times a second on the household's
rollout channel (`backend.broker.rollout_channel`), so the scene shows the run as it happens.

Best effort, like every live update: Redis being away, or anything else going wrong here, never stops
training (the failure is logged once), and the learner never waits for Redis (a sender thread does)."""

import base64
import io
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from PIL import Image

from backend import broker

logger = logging.getLogger(__name__)

ROLLOUT_HZ = float(os.environ.get("VARBOT_LIVE_ROLLOUT_HZ", 10.0))  # 0: publish nothing


def encode_png(image: np.ndarray) -> str:
    """uint8 (H, W, 3) → base64 PNG (lossless, so the scene embeds exactly what the learner saw). Level 1:
    a 96 px frame encodes in under a millisecond."""
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG", compress_level=1)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


class RolloutPublisher:
    """The `on_rollout_step` hook of `PPOTrainer.train`: keeps env 0's steps at `rate_hz` and publishes one
    compact JSON message per kept step. Encoding and sending happen in a sender thread, so the learner only
    hands a step over (waiting for Redis on a busy machine took milliseconds); a step that comes while the
    previous message is still on its way is skipped. `close()` (or leaving the `with` block) sends what is
    pending and stops the thread."""

    def __init__(
        self,
        household_id: int,
        run_id: int,
        robot_id: int,
        world: str,
        stage: str,
        goal_clip_ids: Sequence[int] | None = None,
        rate_hz: float = ROLLOUT_HZ,
        send: Callable[[str, dict[str, Any]], bool] = broker.publish,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}; to publish nothing, pass no hook")
        self.channel = broker.rollout_channel(household_id)
        self.header = {
            "type": "rollout",
            "run_id": run_id,
            "robot_id": robot_id,
            "world": world,
            "stage": stage,
        }
        self.goal_clip_ids = list(goal_clip_ids) if goal_clip_ids is not None else None
        self.send = send
        self.interval_s = 1.0 / rate_hz
        self.next_at = 0.0
        self.ended_since_last = False
        self.published = 0
        self.failed = False
        self.pending: queue.Queue[tuple[Any, bool] | None] = queue.Queue(maxsize=1)
        self.sender: threading.Thread | None = None

    def __call__(self, step: Any) -> None:
        """`step` is a `learning.rl.ppo.RolloutStep` (not imported here: this module stays torch-free)."""
        self.ended_since_last |= step.episode_ended
        now = time.monotonic()
        if now < self.next_at:
            return
        try:
            self.pending.put_nowait((step, self.ended_since_last, time.time()))
        except queue.Full:
            return  # the previous message is still on its way
        self.next_at = now + self.interval_s
        self.ended_since_last = False
        if self.sender is None or not self.sender.is_alive():
            self.sender = threading.Thread(target=self._send_forever, name="live-rollouts", daemon=True)
            self.sender.start()

    def close(self) -> None:
        if self.sender is not None and self.sender.is_alive():
            self.pending.put(None)
            self.sender.join()

    def __enter__(self) -> "RolloutPublisher":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def message(
        self, step: Any, episode_ended: bool = False, taken_at: float | None = None
    ) -> dict[str, Any]:
        """`taken_at`: when the learner's step was taken for sending (throttled), not when encoding ended."""
        return {
            **self.header,
            "step": int(step.global_step),
            "image_png": encode_png(step.image),
            "reward": float(step.reward),
            "episode_ended": episode_ended,
            "goal_clip_id": self._clip_id(step.goal_clip),
            "mirror": step.mirror(),
            "sent_at": time.time() if taken_at is None else taken_at,
        }

    def _send_forever(self) -> None:
        while (item := self.pending.get()) is not None:
            try:
                if self.send(self.channel, self.message(*item)):
                    self.published += 1
            except Exception as error:  # the live view is a convenience: training goes on without it
                self._log_failure(error)

    def _clip_id(self, goal_clip: int) -> int | None:
        if self.goal_clip_ids is None or not 0 <= goal_clip < len(self.goal_clip_ids):
            return None
        return int(self.goal_clip_ids[goal_clip])

    def _log_failure(self, error: Exception) -> None:
        if not self.failed:
            logger.warning("live rollouts stopped being published (training goes on): %r", error)
        self.failed = True
