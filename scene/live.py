"""Following training live: a background thread reads the household's rollout channel
(`backend.broker.rollout_channel`, published by `worker.live`) and keeps the newest rollout of each run; the
scene's loop shows it instead of its own exploration while messages keep coming (`FOLLOW_TIMEOUT_S`)."""

import base64
import binascii
import io
import json
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import redis
from PIL import Image

from backend import broker

logger = logging.getLogger(__name__)

FOLLOW_TIMEOUT_S = 3.0  # no message for this long: the run is no longer followed
RECONNECT_S = 2.0
POLL_S = 0.25
STAGE_NAMES = {"policy_improve": "policy stage", broker.COACHING_STAGE: "coaching by voice"}


class RolloutMessageError(ValueError):
    """A message on the rollout channel that is not a rollout this scene can show."""


@dataclass(frozen=True)
class LiveRollout:
    """One published step of env 0 of a training run, decoded."""

    run_id: int
    robot_id: int | None
    world: str
    stage: str
    step: int
    image: np.ndarray  # uint8 (H, W, 3)
    reward: float
    episode_ended: bool  # since the previous message
    goal_clip_id: int | None
    mirror: dict[str, Any]  # sim.mirror state of env 0
    sequence: int  # counts received messages: a new one has a higher number
    received_at: float  # time.monotonic()

    @property
    def stage_name(self) -> str:
        return STAGE_NAMES.get(self.stage, self.stage.replace("_", " "))


def decode_rollout(data: bytes | str, sequence: int, received_at: float) -> LiveRollout:
    try:
        message = json.loads(data)
        if message.get("type") != "rollout":
            raise RolloutMessageError(f"not a rollout message (type {message.get('type')!r})")
        return LiveRollout(
            run_id=int(message["run_id"]),
            robot_id=_optional_int(message.get("robot_id")),
            world=str(message["world"]),
            stage=str(message.get("stage", "training")),
            step=int(message["step"]),
            image=_decode_png(message["image_png"]),
            reward=float(message["reward"]),
            episode_ended=bool(message.get("episode_ended", False)),
            goal_clip_id=_optional_int(message.get("goal_clip_id")),
            mirror=_checked_mirror(message["mirror"]),
            sequence=sequence,
            received_at=received_at,
        )
    except RolloutMessageError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError, OSError, binascii.Error) as error:
        raise RolloutMessageError(f"unreadable rollout message: {type(error).__name__}: {error}") from error


def _optional_int(value: Any) -> int | None:
    return None if value is None else int(value)


def _decode_png(text: str) -> np.ndarray:
    with Image.open(io.BytesIO(base64.b64decode(text, validate=True))) as image:
        array = np.array(image.convert("RGB"))  # writable: torch reads it for the sphere marker
    if array.ndim != 3 or min(array.shape[:2]) < 8:
        raise RolloutMessageError(f"the camera image is {array.shape}, not a picture")
    return array


def _checked_mirror(mirror: Any) -> dict[str, Any]:
    if not isinstance(mirror, dict) or not {"base", "joints", "bodies"} <= set(mirror):
        raise RolloutMessageError("the mirror state needs 'base', 'joints' and 'bodies' (see sim/mirror.py)")
    return mirror


class RolloutFeed:
    """Subscribes to one household's rollout channel in a daemon thread; survives Redis going away."""

    def __init__(self, household_id: int, timeout_s: float = FOLLOW_TIMEOUT_S) -> None:
        self.channel = broker.rollout_channel(household_id)
        self.timeout_s = timeout_s
        self.stopping = threading.Event()
        self.subscribed = threading.Event()
        self.received = 0
        self.rejected = 0
        self.error: str | None = None
        self._lock = threading.Lock()
        self._runs: dict[int, LiveRollout] = {}
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._listen_forever, name="scene-rollouts", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.stopping.set()
        if self._thread is not None:
            self._thread.join(RECONNECT_S + 1.0)

    def latest(self, prefer_run: int | None = None) -> LiveRollout | None:
        """The newest rollout of `prefer_run` while it keeps coming, else of the run heard from last; None
        when no run was heard from within `timeout_s`."""
        now = time.monotonic()
        with self._lock:
            fresh = [r for r in self._runs.values() if now - r.received_at <= self.timeout_s]
        preferred = [r for r in fresh if r.run_id == prefer_run]
        candidates = preferred or fresh
        return max(candidates, key=lambda r: r.sequence) if candidates else None

    def _listen_forever(self) -> None:
        while not self.stopping.is_set():
            try:
                self._listen()
            except (redis.RedisError, OSError) as error:
                self.subscribed.clear()
                self.error = f"{type(error).__name__}: {error}"
                self.stopping.wait(RECONNECT_S)

    def _listen(self) -> None:
        pubsub = broker.redis_client().pubsub()
        try:
            pubsub.subscribe(self.channel)
            while not self.stopping.is_set():
                message = pubsub.get_message(timeout=POLL_S)
                if message is None:
                    continue
                if message["type"] == "subscribe":  # Redis confirmed: from now on nothing is missed
                    self.subscribed.set()
                    self.error = None
                elif message["type"] == "message":
                    self._receive(message["data"])
        finally:
            pubsub.close()

    def _receive(self, data: bytes | str) -> None:
        try:
            rollout = decode_rollout(data, self.received + 1, time.monotonic())
        except RolloutMessageError as error:
            self.rejected += 1
            if self.rejected == 1 or self.rejected % 100 == 0:  # a mismatched worker would send ~10 a second
                logger.warning("ignored %d message(s) on %s, lastly: %s", self.rejected, self.channel, error)
            return
        with self._lock:
            self.received += 1
            self._runs[rollout.run_id] = rollout
            stale = [k for k, r in self._runs.items() if rollout.received_at - r.received_at > self.timeout_s]
            for run_id in stale:
                del self._runs[run_id]
