"""Talking to the workers: Celery tasks are sent by name (the API never imports their code) and run updates
travel over Redis pub/sub. The task names, queues and channel format here are the contract with worker/."""

import json
from functools import lru_cache
from typing import Any

import redis
from celery import Celery

from backend.models import RunKind
from backend.settings import get_settings

QUEUE_ROBOT = "robot"
QUEUE_TRAINING = "training"
TASK_CAPTURE_SNAPSHOTS = "varbot.capture_snapshots"
TASK_TRY_COMMANDS = "varbot.try_commands"  # the robot's attempts at the household's commands
TASK_ADAPT_TO_ROOM = "varbot.adapt_to_room"  # a robot's model adapted to its room's views
TASK_COACH = "varbot.coach"  # a coaching-by-voice session (backend/services/coaching.py)
COACHING_STAGE = "coaching"  # the `stage` of a coaching session's rollouts on the rollout channel
RUN_TASKS: dict[RunKind, str] = {
    RunKind.FINETUNE: "varbot.finetune",
    RunKind.VAR_FINETUNE: "varbot.var_finetune",
    RunKind.POLICY_IMPROVE: "varbot.policy_improve",
    RunKind.EVALUATE: "varbot.evaluate",
}


class BrokerUnavailable(RuntimeError):
    pass


def run_channel(household_id: int) -> str:
    """Pub/sub channel carrying `{"type": "run", "run": RunPublic}` messages for one household."""
    return f"varbot:runs:{household_id}"


def rollout_channel(household_id: int) -> str:
    """Pub/sub channel of live training rollouts for one household's scene, about 10 messages a second
    while a run's policy stage runs: `{"type": "rollout", "run_id", "robot_id", "world", "stage", "step",
    "image_png" (base64 PNG of env 0's camera), "reward", "episode_ended" (since the last message),
    "goal_clip_id" (or null), "mirror" (env 0's pose, see sim/mirror.py), "sent_at" (Unix time the
    worker took the step; at most 10 a second)}`."""
    return f"varbot:rollouts:{household_id}"


def attempts_status_key(task_id: str) -> str:
    """Redis key of a `TASK_TRY_COMMANDS` task's state: JSON {"state": queued | running | done | refused |
    failed, "message", "created" (attempts stored), "random_views", "robot_id"}; the API writes it queued, the
    worker the rest."""
    return f"varbot:attempts:{task_id}"


def adaptation_status_key(task_id: str) -> str:
    """Redis key of a `TASK_ADAPT_TO_ROOM` task's state: JSON {"state": queued | running | done | refused |
    failed, "message", "version_id" (the adapted version, when done), "robot_id"}."""
    return f"varbot:adaptations:{task_id}"


@lru_cache
def celery_client() -> Celery:
    client = Celery("varbot", broker=get_settings().celery_broker_url)
    client.conf.update(
        task_serializer="json",
        broker_connection_timeout=3,
        broker_connection_retry_on_startup=False,
        broker_transport_options={"socket_timeout": 3, "socket_connect_timeout": 3},
    )
    return client


def send_task(name: str, kwargs: dict[str, Any], queue: str, task_id: str) -> str:
    try:
        celery_client().send_task(
            name,
            kwargs=kwargs,
            queue=queue,
            task_id=task_id,
            retry=True,
            retry_policy={"max_retries": 1, "interval_start": 0, "interval_step": 0.5},
        )
    except Exception as exc:  # kombu raises a zoo of connection errors
        raise BrokerUnavailable(f"the task queue (Redis) is not reachable: {exc}") from exc
    return task_id


@lru_cache
def redis_client() -> redis.Redis:
    return redis.Redis.from_url(get_settings().redis_url, socket_timeout=2, socket_connect_timeout=2)


def publish(channel: str, message: dict[str, Any]) -> bool:
    """Best effort: live updates are a convenience; the database stays the truth (streams also poll it)."""
    try:
        redis_client().publish(channel, json.dumps(message, default=str))
        return True
    except redis.RedisError:
        return False


def broker_status() -> str:
    try:
        redis_client().ping()
        return "ok"
    except redis.RedisError as exc:
        return f"unreachable: {exc}"
