"""`GET /api/v1/system/queues` (admins): how many tasks wait on each queue and which workers answer.

Read-only and cheap: one LLEN per queue (kombu's Redis transport keeps a queue as a list named after it) and
one Celery broadcast ping with a short timeout."""

import redis
from fastapi import APIRouter
from pydantic import BaseModel

from backend import broker
from backend.deps import AdminDep

router = APIRouter(prefix="/system", tags=["system"])
PING_TIMEOUT_S = 1.0


class QueueState(BaseModel):
    name: str
    waiting: int


class WorkerState(BaseModel):
    name: str
    queues: list[str]


class SystemQueues(BaseModel):
    queues: list[QueueState]
    workers: list[WorkerState]
    workers_message: str


@router.get("/queues", response_model=SystemQueues)
def queues(_caller: AdminDep) -> SystemQueues:
    names = (broker.QUEUE_TRAINING, broker.QUEUE_ROBOT)
    try:
        client = broker.redis_client()
        waiting = [QueueState(name=name, waiting=int(client.llen(name))) for name in names]  # type: ignore[arg-type]
    except redis.RedisError as exc:
        return SystemQueues(
            queues=[], workers=[], workers_message=f"the broker (Redis) is unreachable: {exc}"
        )
    try:
        answers = broker.celery_client().control.inspect(timeout=PING_TIMEOUT_S).active_queues() or {}
    except Exception as exc:  # kombu raises many connection error types
        answers, problem = {}, f"could not ask the workers: {exc}"
    else:
        problem = ""
    workers = [
        WorkerState(name=name, queues=sorted(q["name"] for q in listed))
        for name, listed in sorted(answers.items())
    ]
    message = problem or (
        ""
        if workers
        else "no worker answered: start one with `varbot worker --queue training` (or `varbot up`)"
    )
    return SystemQueues(queues=waiting, workers=workers, workers_message=message)
